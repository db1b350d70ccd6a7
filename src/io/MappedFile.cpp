#include "MappedFile.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <new>

#include "sonoslice/core/Error.h"

namespace sonoslice {

std::shared_ptr<void> map_file_region(const std::string& path, uint64_t offset, uint64_t length,
                                      size_t alignment) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw FileError("cannot open '" + path + "': " + std::strerror(errno));
  struct stat st;
  if (::fstat(fd, &st) != 0 || uint64_t(st.st_size) < offset + length) {
    ::close(fd);
    throw FileError("cannot read '" + path + "': truncated file (" + std::to_string(st.st_size) +
                    " bytes, " + std::to_string(offset + length) + " needed)");
  }
  if (alignment > 1 && offset % alignment != 0) {
    // A mapping would start the data at a misaligned address (a header whose length is not a
    // multiple of the value size): read it into memory that is aligned instead.
    std::shared_ptr<void> copy(::operator new(size_t(std::max<uint64_t>(length, 1))),
                               [](void* p) { ::operator delete(p); });
    uint64_t done = 0;
    while (done < length) {
      const ssize_t n = ::pread(fd, static_cast<char*>(copy.get()) + done,
                                size_t(std::min<uint64_t>(length - done, uint64_t(1) << 30)),
                                off_t(offset + done));
      if (n <= 0) {
        const int err = n < 0 ? errno : 0;
        ::close(fd);
        throw FileError("cannot read '" + path +
                        "': " + (err ? std::strerror(err) : std::string("truncated file")));
      }
      done += uint64_t(n);
    }
    ::close(fd);
    return copy;
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
