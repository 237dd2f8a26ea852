// The peak resident memory of one benchmark case, not of the whole process.
//
// Google Benchmark calls a case's function more than once in one process (a trial run to size
// the iterations, then the timed run), and memory the previous call freed on worker threads can
// stay resident in their malloc arenas: the process's ru_maxrss then counts two simulations'
// worth of some buffers (bench_mpm_step reported 176 bytes per particle where a process running
// one simulation peaks at 163). `reset_peak_rss()` returns freed memory to the system
// (malloc_trim) and restarts the kernel's high-water mark (writing 5 to /proc/self/clear_refs,
// Linux 4.0 and later, see proc(5)); `peak_rss_bytes()` then reads VmHWM from /proc/self/status.
// Where clear_refs cannot be written, the mark is the process's, as before (the result then
// says so with reset = false).
//
// glibc also raises its mmap threshold (up to 32 MB) the first time a large mmapped block is
// freed; after that, vectors growing by doubling leave their old buffers in the heap, where
// they stay resident. A fresh process (`slurry run`) has not freed one yet when it seeds its
// particles, a second benchmark case has: `fresh_process_malloc()` pins the threshold at
// glibc's default (128 KiB, mallopt(3)) so that every case allocates as a fresh process does.
#pragma once
#include <malloc.h>
#include <sys/resource.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>

namespace slurry::bench {

inline void fresh_process_malloc() { mallopt(M_MMAP_THRESHOLD, 128 * 1024); }

inline bool reset_peak_rss() {
  malloc_trim(0);
  std::FILE* f = std::fopen("/proc/self/clear_refs", "w");
  if (!f) return false;
  const bool ok = std::fputs("5", f) >= 0;
  return std::fclose(f) == 0 && ok;
}

inline double peak_rss_bytes() {
  if (std::FILE* f = std::fopen("/proc/self/status", "r")) {
    char line[256];
    long kb = -1;
    while (std::fgets(line, sizeof line, f))
      if (std::strncmp(line, "VmHWM:", 6) == 0) kb = std::atol(line + 6);
    std::fclose(f);
    if (kb >= 0) return double(kb) * 1024.0;
  }
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return double(usage.ru_maxrss) * 1024.0;
}

}  // namespace slurry::bench
