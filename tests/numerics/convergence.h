#pragma once
// Helpers shared by the numerics tests: observed convergence order and its reporting.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <string>
#include <vector>

namespace slurry::numerics::test {

/// Slope of the least-squares line through (log h_i, log e_i): the observed order p of e ~ C h^p.
inline double fitted_order(const std::vector<double>& h, const std::vector<double>& err) {
  const std::size_t n = h.size();
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double x = std::log(h[i]), y = std::log(err[i]);
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
  }
  const double dn = static_cast<double>(n);
  return (dn * sxy - sx * sy) / (dn * sxx - sx * sx);
}

/// Prints the refinement table and the fitted order, records it as a test property, returns it.
inline double report_order(const std::string& name, const std::vector<double>& h,
                           const std::vector<double>& err) {
  const double p = fitted_order(h, err);
  std::cout << "[order] " << name << ": " << p << "   (h, error):";
  for (std::size_t i = 0; i < h.size(); ++i) std::cout << " (" << h[i] << ", " << err[i] << ")";
  std::cout << "\n";
  ::testing::Test::RecordProperty("order_" + name, std::to_string(p));
  return p;
}

}  // namespace slurry::numerics::test
