#include "MappedFile.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "sonoslice/core/Error.h"

namespace sonoslice {

std::shared_ptr<void> map_file_region(const std::string& path, uint64_t offset, uint64_t length) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw FileError("cannot open '" + path + "': " + std::strerror(errno));
  struct stat st;
  if (::fstat(fd, &st) != 0 || uint64_t(st.st_size) < offset + length) {
    ::close(fd);
    throw FileError("cannot read '" + path + "': truncated file (" + std::to_string(st.st_size) +
                    " bytes, " + std::to_string(offset + length) + " needed)");
  }
  const uint64_t page = uint64_t(::sysconf(_SC_PAGE_SIZE));
  const uint64_t start = offset / page * page, skip = offset - start;
  void* base = ::mmap(nullptr, size_t(length + skip), PROT_READ, MAP_PRIVATE, fd, off_t(start));
  ::close(fd);  // the mapping keeps the file
  if (base == MAP_FAILED) throw FileError("cannot map '" + path + "': " + std::strerror(errno));
  const size_t mapped = size_t(length + skip);
  // Reads ahead: slicing touches the volume in no particular order.
  ::madvise(base, mapped, MADV_WILLNEED);
  return std::shared_ptr<void>(static_cast<char*>(base) + skip,
                               [base, mapped](void*) { ::munmap(base, mapped); });
}

}  // namespace sonoslice
