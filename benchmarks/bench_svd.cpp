// 3x3 SVD throughput: slurry::constitutive::svd against Eigen::JacobiSVD, float and double,
// on a pool of deformation-gradient-like matrices (identity plus uniform noise of size 0.3,
// i.e. rotations, stretches and shears of tens of percent). Counter "svd/s": decompositions per
// second on one core. BM_LanesSvd3 is the batched SVD of svd_lanes.h, a batch of 16 floats or 8
// doubles per call, gathering each batch from the pool as the MPM's P2G does.
#include <benchmark/benchmark.h>

#include <Eigen/SVD>
#include <random>
#include <vector>

#include "slurry/constitutive/svd.h"
#include "slurry/constitutive/svd_lanes.h"

namespace {

constexpr int kPool = 4096;  // 4096 * 9 * 8 B = 288 KiB of doubles: mostly in L2, as in P2G

template <class T>
std::vector<Eigen::Matrix<T, 3, 3>> make_pool() {
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  std::vector<Eigen::Matrix<T, 3, 3>> pool(kPool);
  for (auto& F : pool) {
    F.setIdentity();
    for (int i = 0; i < 9; ++i) F(i) += T(u(rng));
  }
  return pool;
}

/// Times fn(F) over the pool; counter: decompositions per second.
template <class Pool, class Fn>
void time_pool(benchmark::State& state, const Pool& pool, Fn&& fn) {
  std::int64_t n = 0;
  for (auto _ : state) {
    for (const auto& F : pool) fn(F);
    n += std::int64_t(pool.size());
  }
  state.counters["svd/s"] = benchmark::Counter(double(n), benchmark::Counter::kIsRate);
}

template <class T, int D>
void our_svd(const Eigen::Matrix<T, D, D>& F) {
  Eigen::Matrix<T, D, D> U, V;
  Eigen::Matrix<T, D, 1> sigma;
  slurry::constitutive::svd(F, U, sigma, V);
  benchmark::DoNotOptimize(U.data());
  benchmark::DoNotOptimize(V.data());
  benchmark::DoNotOptimize(sigma.data());
}

template <class T>
void BM_SlurrySvd3(benchmark::State& state) {
  time_pool(state, make_pool<T>(), [](const auto& F) { our_svd<T, 3>(F); });
}

template <class T>
void BM_LanesSvd3(benchmark::State& state) {
  namespace lanes = slurry::constitutive::lanes;
  constexpr int W = lanes::kWidth<T>;
  const auto pool = make_pool<T>();
  std::int64_t n = 0;
  for (auto _ : state) {
    for (std::size_t b = 0; b + W <= pool.size(); b += W) {
      lanes::Mat3<T, W> F, U, V;
      lanes::Vec3<T, W> sigma;
      for (int l = 0; l < W; ++l) F.put(l, pool[b + std::size_t(l)]);
      lanes::svd(F, U, sigma, V);
      benchmark::DoNotOptimize(&U);
      benchmark::DoNotOptimize(&V);
      benchmark::DoNotOptimize(&sigma);
    }
    n += std::int64_t(pool.size());
  }
  state.counters["svd/s"] = benchmark::Counter(double(n), benchmark::Counter::kIsRate);
}

template <class T>
void BM_EigenJacobiSvd3(benchmark::State& state) {
  time_pool(state, make_pool<T>(), [](const auto& F) {
    Eigen::JacobiSVD<Eigen::Matrix<T, 3, 3>> svd(F, Eigen::ComputeFullU | Eigen::ComputeFullV);
    benchmark::DoNotOptimize(svd.matrixU().data());
    benchmark::DoNotOptimize(svd.matrixV().data());
    benchmark::DoNotOptimize(svd.singularValues().data());
  });
}

template <class T>
void BM_SlurryPolar3(benchmark::State& state) {
  time_pool(state, make_pool<T>(), [](const auto& F) {
    Eigen::Matrix<T, 3, 3> R, S;
    slurry::constitutive::polar(F, R, S);
    benchmark::DoNotOptimize(R.data());
    benchmark::DoNotOptimize(S.data());
  });
}

template <class T>
void BM_SlurrySvd2(benchmark::State& state) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  std::vector<Eigen::Matrix<T, 2, 2>> pool(kPool);
  for (auto& F : pool) {
    F.setIdentity();
    for (int i = 0; i < 4; ++i) F(i) += T(u(rng));
  }
  time_pool(state, pool, [](const auto& F) { our_svd<T, 2>(F); });
}

BENCHMARK_TEMPLATE(BM_SlurrySvd3, float);
BENCHMARK_TEMPLATE(BM_LanesSvd3, float);
BENCHMARK_TEMPLATE(BM_EigenJacobiSvd3, float);
BENCHMARK_TEMPLATE(BM_SlurrySvd3, double);
BENCHMARK_TEMPLATE(BM_LanesSvd3, double);
BENCHMARK_TEMPLATE(BM_EigenJacobiSvd3, double);
BENCHMARK_TEMPLATE(BM_SlurryPolar3, float);
BENCHMARK_TEMPLATE(BM_SlurryPolar3, double);
BENCHMARK_TEMPLATE(BM_SlurrySvd2, float);
BENCHMARK_TEMPLATE(BM_SlurrySvd2, double);

}  // namespace

BENCHMARK_MAIN();
