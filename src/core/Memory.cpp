#include "sonoslice/core/Memory.h"

#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <string>

namespace sonoslice {

unsigned long long available_memory_bytes() {
  std::ifstream meminfo("/proc/meminfo");
  std::string line;
  while (std::getline(meminfo, line)) {
    unsigned long long kib = 0;
    if (std::sscanf(line.c_str(), "MemAvailable: %llu kB", &kib) == 1) return kib * 1024ull;
  }
  const long pages = ::sysconf(_SC_AVPHYS_PAGES), page = ::sysconf(_SC_PAGE_SIZE);
  return pages > 0 && page > 0 ? static_cast<unsigned long long>(pages) * page : ~0ull;
}

}  // namespace sonoslice
