#include "sonoslice/io/AtomicFile.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/random.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <random>
#include <string>

#include "sonoslice/core/Error.h"
#include "sonoslice/io/VolumeFile.h"

namespace fs = std::filesystem;

namespace sonoslice {
namespace {

const char kTempPrefix[] = ".tmp-sonoslice-";

// renameat2 through the system call: glibc declares it only from 2.28, the kernel has it since
// 3.15; filesystems without the flags answer EINVAL, old kernels ENOSYS (callers fall back).
constexpr unsigned kRenameNoReplace = 1u << 0;  // RENAME_NOREPLACE
constexpr unsigned kRenameExchange = 1u << 1;   // RENAME_EXCHANGE
int rename_with_flags(const std::string& from, const std::string& to, unsigned flags) {
  return int(::syscall(SYS_renameat2, AT_FDCWD, from.c_str(), AT_FDCWD, to.c_str(), flags));
}

fs::path parent_of(const std::string& path) {
  fs::path parent = fs::path(path).parent_path();
  return parent.empty() ? fs::path(".") : parent;
}

// 12 characters from the kernel's random source: 62^12 names, so a temporary's name cannot be
// guessed in advance (and a name someone planted is simply skipped: O_EXCL).
std::string random_token() {
  static const char kAlphabet[] = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789";
  unsigned char bytes[12];
  if (::getrandom(bytes, sizeof bytes, 0) != ssize_t(sizeof bytes)) {
    std::random_device device;
    for (unsigned char& b : bytes) b = static_cast<unsigned char>(device());
  }
  std::string token;
  for (unsigned char b : bytes) token += kAlphabet[b % 62];
  return token;
}

fs::path temp_name_beside(const fs::path& target) {
  // A file name holds 255 bytes; the prefix and token take 28 of them.
  return parent_of(target.string()) /
         (kTempPrefix + random_token() + "." + target.filename().string().substr(0, 200));
}

// --- the registry of live temporaries, read by the signal handler ------------------------------
//
// Fixed storage and lock-free atomics only: a handler may run at any instruction of any thread,
// so it can neither allocate nor take a lock. A slot is claimed (kClaimed), filled, then
// published (kLive); the handler only reads kLive slots.
enum SlotState : int { kFree = 0, kClaimed = 1, kLive = 2 };
enum SlotKind : int {
  kRemoveFile,    // unlink(path)
  kRemoveFolder,  // empty the (flat) folder at path, then rmdir
  kRestore,       // rename(path, target): a folder moved aside during a replacement goes back
};
constexpr int kSlotCount = 64;
constexpr size_t kSlotPathBytes = 4096;
struct Slot {
  std::atomic<int> state{kFree};
  int kind = kRemoveFile;
  char path[kSlotPathBytes];
  char target[kSlotPathBytes];
};
static_assert(std::atomic<int>::is_always_lock_free, "the signal handler reads slot states");
Slot g_slots[kSlotCount];

// Returns the slot, or -1 when the registry is full or the path too long: the output is then
// still written safely, only not cleaned up on a signal.
int registry_add(SlotKind kind, const std::string& path, const std::string& target = "") {
  std::error_code ec;
  // Absolute: the handler must not depend on the current folder at the time of the signal.
  const std::string p = fs::absolute(path, ec).string();
  const std::string t = target.empty() || ec ? std::string() : fs::absolute(target, ec).string();
  if (ec || p.size() >= kSlotPathBytes || t.size() >= kSlotPathBytes) return -1;
  for (int i = 0; i < kSlotCount; ++i) {
    int expected = kFree;
    if (!g_slots[i].state.compare_exchange_strong(expected, kClaimed)) continue;
    g_slots[i].kind = kind;
    std::memcpy(g_slots[i].path, p.c_str(), p.size() + 1);
    std::memcpy(g_slots[i].target, t.c_str(), t.size() + 1);
    g_slots[i].state.store(kLive, std::memory_order_release);
    return i;
  }
  return -1;
}

void registry_remove(int slot) {
  if (slot >= 0) g_slots[slot].state.store(kFree, std::memory_order_release);
}

// Empties a flat folder (the temporaries are never nested) and removes it, with raw system calls
// only: opendir/readdir may allocate, which a signal handler must not.
void remove_folder_from_handler(const char* path) {
  const int fd = ::open(path, O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
  if (fd >= 0) {
    alignas(8) char buffer[8192];
    // Removing entries while listing may skip some on some filesystems: list again until a pass
    // finds nothing left to remove.
    for (int pass = 0; pass < 64; ++pass) {
      bool removed = false;
      ::lseek(fd, 0, SEEK_SET);
      long n;
      while ((n = ::syscall(SYS_getdents64, fd, buffer, sizeof buffer)) > 0) {
        for (long at = 0; at < n;) {
          // struct linux_dirent64: d_ino (8 bytes), d_off (8), d_reclen (2), d_type (1), d_name.
          unsigned short length;
          std::memcpy(&length, buffer + at + 16, sizeof length);
          const char* name = buffer + at + 19;
          at += length;
          if (std::strcmp(name, ".") == 0 || std::strcmp(name, "..") == 0) continue;
          if (::unlinkat(fd, name, 0) == 0) removed = true;
        }
      }
      if (!removed) break;
    }
    ::close(fd);
  }
  ::rmdir(path);
}

extern "C" void remove_outputs_on_signal(int signal_number) {
  const int saved_errno = errno;
  for (Slot& slot : g_slots) {
    if (slot.state.load(std::memory_order_acquire) != kLive) continue;
    switch (slot.kind) {
      case kRemoveFile:
        ::unlink(slot.path);
        break;
      case kRemoveFolder:
        remove_folder_from_handler(slot.path);
        break;
      case kRestore:
        // Fails only when the new folder is already in place; the old one is then obsolete.
        if (::rename(slot.path, slot.target) != 0) remove_folder_from_handler(slot.path);
        break;
    }
  }
  // Die of the signal as the process would have without us (exit status, parent's view).
  struct sigaction default_action {};
  default_action.sa_handler = SIG_DFL;
  sigemptyset(&default_action.sa_mask);
  ::sigaction(signal_number, &default_action, nullptr);
  errno = saved_errno;
  ::raise(signal_number);  // delivered when this handler returns (the signal is blocked in it)
}

// --- folders of images ---------------------------------------------------------------------------

// The names sonoslice writes into a PNG folder (docs/conventions.md §6): img_<5 or more digits>.png
// and poses.txt. Nothing else in a folder may be deleted by replacing it.
bool is_stack_file_name(const std::string& name) {
  if (name == "poses.txt") return true;
  if (name.size() < 4 + 5 + 4 || name.compare(0, 4, "img_") != 0 ||
      name.compare(name.size() - 4, 4, ".png") != 0)
    return false;
  return std::all_of(name.begin() + 4, name.end() - 4, [](char c) { return c >= '0' && c <= '9'; });
}

// A folder output's destination: absolute, normalised, with links resolved, so that `--out ..`
// or a link to a folder name the folder that is really replaced.
fs::path folder_target(const std::string& path) {
  std::error_code ec;
  fs::path p = fs::weakly_canonical(fs::absolute(path, ec), ec);
  if (ec) p = fs::absolute(path).lexically_normal();
  if (!p.has_filename() && p != p.root_path()) p = p.parent_path();  // "a/b/" → "a/b"
  return p;
}

// FileError unless the folder at `target` holds nothing but files sonoslice wrote there.
void check_replaceable_folder(const std::string& path, const fs::path& target) {
  std::error_code ec;
  fs::directory_iterator it(target, ec), end;
  if (ec)
    throw FileError("cannot replace folder '" + path + "': " + ec.message() +
                    " (sonoslice replaces a folder only after checking that it holds nothing but "
                    "its own images)");
  std::string first;
  size_t foreign = 0;
  for (; it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    std::error_code type_ec;
    if (is_stack_file_name(name) && it->symlink_status(type_ec).type() == fs::file_type::regular)
      continue;
    if (foreign++ == 0) first = name;
  }
  if (foreign > 0)
    throw FileError("cannot write PNG folder '" + path + "': it holds '" + first + "'" +
                    (foreign > 1 ? " and " + std::to_string(foreign - 1) + " more" : "") +
                    ", which sonoslice did not write; it replaces only folders holding nothing but "
                    "its own images (img_NNNNN.png, poses.txt): give a new or empty folder");
}

// Deletes a previous image folder after it has been replaced: only the files sonoslice wrote, so
// a file someone put there in the meantime survives (and so does the folder, with a warning).
void remove_old_image_folder(const fs::path& folder, const std::string& path) {
  std::error_code ec;
  for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code type_ec;
    if (is_stack_file_name(it->path().filename().string()) &&
        it->symlink_status(type_ec).type() == fs::file_type::regular)
      ::unlink(it->path().c_str());
  }
  if (::rmdir(folder.c_str()) != 0)
    warn("the previous contents of '" + path + "' were kept in '" + folder.string() +
         "': files sonoslice did not write appeared in it while it was being replaced");
}

// Opens `file`, flushes it to disk and closes it; FileError naming `path` on any failure.
void sync_file(const std::string& file, const std::string& path) {
  const int fd = ::open(file.c_str(), O_RDONLY | O_NOFOLLOW | O_CLOEXEC);
  if (fd < 0) throw FileError(write_error_message(path, errno));
  const bool synced = ::fsync(fd) == 0;
  const int error_number = errno;
  if (::close(fd) != 0 && synced) throw FileError(write_error_message(path, errno));
  if (!synced) throw FileError(write_error_message(path, error_number));
}

// Makes a rename durable. Not checked: the new file is already in place, and some filesystems
// refuse fsync on folders; failing the run at this point would misreport a completed write.
void sync_folder(const fs::path& folder) {
  const int fd = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

}  // namespace

// --- messages ------------------------------------------------------------------------------------

std::string write_error_reason(int error_number) {
  std::string why;
  switch (error_number) {
    case ENOSPC:
      why = "no space left on device";
      break;
    case EDQUOT:
      why = "disk quota exceeded";
      break;
    case EFBIG:
      why = "file too large (the file-size limit, ulimit -f, or the filesystem's)";
      break;
    default:
      why = std::strerror(error_number);
      if (!why.empty()) why[0] = char(std::tolower(static_cast<unsigned char>(why[0])));
  }
  return why;
}

std::string write_error_message(const std::string& path, int error_number) {
  return "cannot write '" + path + "': " + write_error_reason(error_number);
}

std::string incomplete_write_reason(const std::string& written_file) {
  const fs::path folder = parent_of(written_file);
  struct statvfs fs_info;
  // Writers fill a disk to its last block before failing; 1 MiB of slack covers the blocks a
  // filesystem keeps back and the part of the file the writer still held in buffers.
  if (::statvfs(folder.c_str(), &fs_info) == 0 &&
      uint64_t(fs_info.f_bavail) * fs_info.f_frsize < (uint64_t(1) << 20))
    return "no space left on device";
  struct rlimit limit;
  if (::getrlimit(RLIMIT_FSIZE, &limit) == 0 && limit.rlim_cur != RLIM_INFINITY) {
    // The file and its companions (o.mhd, o.raw): the names that share its stem.
    const std::string stem = fs::path(written_file).filename().string();
    const std::string prefix = stem.substr(0, stem.find('.') + 1);
    std::error_code ec;
    for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
      std::error_code size_ec;
      const std::string name = it->path().filename().string();
      if (name.compare(0, prefix.size(), prefix) == 0 &&
          it->file_size(size_ec) >= uint64_t(limit.rlim_cur) && !size_ec)
        return "file too large (the file-size limit, ulimit -f, is " +
               std::to_string(uint64_t(limit.rlim_cur)) + " bytes)";
    }
  }
  return "";
}

void write_fully(int fd, const void* data, size_t n, const std::string& path) {
  const char* p = static_cast<const char*>(data);
  while (n > 0) {
    // At most 1 GiB per call: Linux writes no more than about 2 GiB at once anyway.
    const ssize_t written = ::write(fd, p, std::min<size_t>(n, size_t(1) << 30));
    if (written < 0) {
      if (errno == EINTR) continue;
      throw FileError(write_error_message(path, errno));
    }
    if (written == 0) throw FileError(write_error_message(path, ENOSPC));
    p += written;
    n -= size_t(written);
  }
}

// --- checks before any work ----------------------------------------------------------------------

namespace {
void check_output_location(const std::string& path, bool directory);

// Permission bits do not tell (root passes access() on /sys and /proc, where nothing can be
// created): a hidden file is created beside the output and removed at once, so that an output
// nobody can write is refused before the work rather than after it.
void try_creating_beside(const std::string& path, const fs::path& target) {
  const std::string probe = temp_name_beside(target).string();
  const int slot = registry_add(kRemoveFile, probe);
  const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0600);
  const int error_number = errno;
  if (fd >= 0) {
    ::close(fd);
    ::unlink(probe.c_str());
  }
  registry_remove(slot);
  if (fd < 0 && error_number != EEXIST)
    throw FileError("cannot write '" + path + "': cannot create files in folder '" +
                    parent_of(target.string()).string() + "' (" + write_error_reason(error_number) +
                    ")");
}
}  // namespace

void check_output_path(const std::string& path, bool directory) {
  check_output_location(path, directory);
  try_creating_beside(path, directory ? folder_target(path) : fs::path(path));
}

namespace {
void check_output_location(const std::string& path, bool directory) {
  if (path.empty()) throw FileError("output path is empty");
  std::error_code ec;
  if (directory) {
    const fs::path target = folder_target(path);
    if (target == target.root_path())
      throw FileError("cannot write PNG folder '" + path + "': that is the root folder");
    const fs::path cwd = fs::weakly_canonical(fs::current_path(ec), ec);
    if (!ec) {
      const auto [t_end, c_end] =
          std::mismatch(target.begin(), target.end(), cwd.begin(), cwd.end());
      (void)c_end;
      if (t_end == target.end())
        throw FileError("cannot write PNG folder '" + path +
                        "': it is the current folder or holds it; give a new or empty folder");
    }
    const fs::path parent = target.parent_path();
    if (!fs::is_directory(parent, ec))
      throw FileError("cannot write '" + path + "': folder '" + parent.string() +
                      "' does not exist");
    if (::access(parent.c_str(), W_OK) != 0)
      throw FileError("cannot write '" + path + "': folder '" + parent.string() +
                      "' is not writable (" + std::strerror(errno) + ")");
    if (fs::exists(fs::symlink_status(target, ec)) && !fs::is_directory(target, ec))
      throw FileError("cannot write PNG folder '" + path + "': a file of that name exists");
    if (fs::is_directory(target, ec)) check_replaceable_folder(path, target);
    return;
  }
  const fs::path parent = parent_of(path);
  if (!fs::is_directory(parent, ec))
    throw FileError("cannot write '" + path + "': directory '" + parent.string() +
                    "' does not exist");
  if (::access(parent.c_str(), W_OK) != 0)
    throw FileError("cannot write '" + path + "': directory '" + parent.string() +
                    "' is not writable (" + std::strerror(errno) + ")");
  if (fs::is_directory(path, ec))
    throw FileError("cannot write '" + path + "': it is an existing directory");
}
}  // namespace

// --- AtomicFile ----------------------------------------------------------------------------------

AtomicFile::AtomicFile(std::string path, OutputKind kind) : path_(std::move(path)), kind_(kind) {
  check_output_location(path_,
                        kind_ == OutputKind::Folder);  // creating the temporary tries the rest
  target_ = kind_ == OutputKind::Folder ? folder_target(path_).string() : path_;
  for (int attempt = 0;; ++attempt) {
    temp_ = temp_name_beside(target_).string();
    // Registered before it exists, so that no instant passes with an unregistered temporary.
    slot_ = registry_add(kind_ == OutputKind::File ? kRemoveFile : kRemoveFolder, temp_);
    int rc;
    if (kind_ == OutputKind::File) {
      // O_EXCL with O_CREAT never follows a link; 0666 leaves the permissions to the umask.
      fd_ = ::open(temp_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0666);
      rc = fd_ < 0 ? -1 : 0;
    } else {
      rc = ::mkdir(temp_.c_str(), kind_ == OutputKind::Staged ? 0700 : 0777);
    }
    if (rc == 0) break;
    const int error_number = errno;
    registry_remove(slot_);
    slot_ = -1;
    if (error_number != EEXIST || attempt >= 100)
      throw FileError(write_error_message(path_, error_number));
  }
  temp_path_ = kind_ == OutputKind::Staged
                   ? (fs::path(temp_) / fs::path(target_).filename()).string()
                   : temp_;
}

AtomicFile::~AtomicFile() {
  if (!committed_) discard();
}

void AtomicFile::discard() noexcept {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  if (kind_ == OutputKind::File) {
    ::unlink(temp_.c_str());
  } else {
    std::error_code ec;
    fs::remove_all(temp_, ec);  // never throws; does not follow links
  }
  registry_remove(slot_);
  slot_ = -1;
}

void AtomicFile::prepare() {
  if (prepared_) return;
  switch (kind_) {
    case OutputKind::File: {
      if (fd_ < 0) throw FileError("cannot write '" + path_ + "': the temporary is closed");
      // fsync reports what delayed allocation only finds out on the way to the disk (ENOSPC,
      // EIO); close can report it too (NFS).
      const bool synced = ::fsync(fd_) == 0;
      const int sync_errno = errno;
      const int closed = ::close(fd_);
      const int close_errno = errno;
      fd_ = -1;
      if (!synced) throw FileError(write_error_message(path_, sync_errno));
      if (closed != 0) throw FileError(write_error_message(path_, close_errno));
      break;
    }
    case OutputKind::Staged: {
      const std::string name = fs::path(target_).filename().string();
      std::error_code ec;
      for (fs::directory_iterator it(temp_, ec), end; !ec && it != end; it.increment(ec))
        staged_.push_back(it->path().filename().string());
      if (ec) throw FileError("cannot write '" + path_ + "': " + ec.message());
      if (std::find(staged_.begin(), staged_.end(), name) == staged_.end())
        throw FileError("cannot write '" + path_ + "': nothing was written");
      for (const std::string& n : staged_) sync_file((fs::path(temp_) / n).string(), path_);
      // Companions first: the named file appears only once the data it refers to is in place.
      std::stable_partition(staged_.begin(), staged_.end(),
                            [&](const std::string& n) { return n != name; });
      break;
    }
    case OutputKind::Folder: {
      // Every image reaches the disk before the folder takes its name: one syncfs for the
      // folder's filesystem rather than an fsync per image (thousands of them).
      const int dir_fd = ::open(temp_.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
      if (dir_fd < 0) throw FileError(write_error_message(path_, errno));
      const bool synced = ::syncfs(dir_fd) == 0 && ::fsync(dir_fd) == 0;
      const int sync_errno = errno;
      ::close(dir_fd);
      if (!synced) throw FileError(write_error_message(path_, sync_errno));
      break;
    }
  }
  prepared_ = true;
}

void AtomicFile::commit() {
  if (committed_) throw Error("'" + path_ + "': output committed twice");
  prepare();
  const fs::path parent = parent_of(target_);
  switch (kind_) {
    case OutputKind::File:
      if (::rename(temp_.c_str(), target_.c_str()) != 0)
        throw FileError(write_error_message(path_, errno));
      break;
    case OutputKind::Staged:
      for (const std::string& n : staged_)
        if (::rename((fs::path(temp_) / n).c_str(), (parent / n).c_str()) != 0)
          throw FileError(write_error_message(path_, errno));
      ::rmdir(temp_.c_str());
      break;
    case OutputKind::Folder: {
      // A new folder: never replace one that appeared since the check.
      if (rename_with_flags(temp_, target_, kRenameNoReplace) == 0) break;
      if (errno != EEXIST && errno != ENOTEMPTY && errno != EINVAL && errno != ENOSYS)
        throw FileError(write_error_message(path_, errno));
      struct stat st;
      if (::lstat(target_.c_str(), &st) != 0) {  // no RENAME_NOREPLACE on this filesystem
        if (::rename(temp_.c_str(), target_.c_str()) != 0)
          throw FileError(write_error_message(path_, errno));
        break;
      }
      // Replace a previous image folder, checked again now: it may have changed since.
      if (!S_ISDIR(st.st_mode))
        throw FileError("cannot write PNG folder '" + path_ + "': a file of that name exists");
      check_replaceable_folder(path_, target_);
      if (rename_with_flags(temp_, target_, kRenameExchange) == 0) {
        // One atomic swap: temp_ now holds the previous folder (still registered for removal).
        remove_old_image_folder(temp_, path_);
        break;
      }
      if (errno != EINVAL && errno != ENOSYS) throw FileError(write_error_message(path_, errno));
      // No exchange on this filesystem: move the old folder aside, the new one in, and put the
      // old one back if that fails (or if a signal comes in between: the kRestore entry).
      const std::string aside = temp_name_beside(target_).string();
      const int restore = registry_add(kRestore, aside, target_);
      if (::rename(target_.c_str(), aside.c_str()) != 0) {
        const int error_number = errno;
        registry_remove(restore);
        throw FileError("cannot replace '" + path_ + "': " + std::strerror(error_number));
      }
      if (::rename(temp_.c_str(), target_.c_str()) != 0) {
        const int error_number = errno;
        ::rename(aside.c_str(), target_.c_str());
        registry_remove(restore);
        throw FileError(write_error_message(path_, error_number));
      }
      remove_old_image_folder(aside, path_);
      registry_remove(restore);
      break;
    }
  }
  sync_folder(parent);
  registry_remove(slot_);
  slot_ = -1;
  committed_ = true;
}

void OutputSet::add(std::unique_ptr<AtomicFile> file) {
  files_.push_back(std::move(file));
}

void OutputSet::commit() {
  for (const auto& file : files_) file->prepare();  // where a full disk shows, before any rename
  for (const auto& file : files_) file->commit();
  files_.clear();
}

void write_text_file(const std::string& path, const std::string& text, OutputSet* together) {
  auto file = std::make_unique<AtomicFile>(path);
  write_fully(file->fd(), text.data(), text.size(), path);
  if (together)
    together->add(std::move(file));
  else
    file->commit();
}

unsigned long long free_disk_bytes(const std::string& path) {
  struct statvfs s;
  if (::statvfs(parent_of(path).c_str(), &s) != 0) return ~0ull;
  return static_cast<unsigned long long>(s.f_bavail) * s.f_frsize;
}

// --- distinct outputs ----------------------------------------------------------------------------

namespace {

// The path a file is known by: absolute, normalised, links in it resolved.
fs::path identity_of(const fs::path& p) {
  std::error_code ec;
  fs::path out = fs::weakly_canonical(fs::absolute(p, ec), ec);
  if (ec) out = fs::absolute(p).lexically_normal();
  if (!out.has_filename() && out != out.root_path()) out = out.parent_path();
  return out;
}

// The files reading or writing `path` touches: the file, and what its format keeps beside it.
std::vector<fs::path> files_of(const std::string& path, bool companions = true) {
  const fs::path p = identity_of(path);
  std::vector<fs::path> files{p};
  if (!companions) return files;
  const std::string ext = file_extension(path);
  auto with = [&](const char* extension) {
    fs::path q = p;
    files.push_back(q.replace_extension(extension));
  };
  if (ext == ".npy") with(".json");  // the geometry sidecar of a volume
  if (ext == ".mhd") with(".raw"), with(".zraw");
  if (ext == ".nhdr") with(".raw"), with(".raw.gz");
  if (ext == ".hdr") with(".img");
  if (ext == ".img") with(".hdr");
  return files;
}

bool same_file(const fs::path& a, const fs::path& b) {
  if (a == b) return true;
  std::error_code ec;
  return fs::exists(a, ec) && fs::exists(b, ec) && fs::equivalent(a, b, ec) && !ec;
}

bool inside(const fs::path& folder, const fs::path& p) {
  const auto [f_end, p_end] = std::mismatch(folder.begin(), folder.end(), p.begin(), p.end());
  return f_end == folder.end() && p_end != p.end();
}

bool is_folder_output(const std::string& path) {
  try {
    return image_format(path, "output") == ImageFormat::Directory;
  } catch (const InputError&) {
    return false;  // an unknown extension: refused later by the writer, with its own message
  }
}

std::string named(const NamedPath& n) {
  return n.flag + " '" + n.path + "'";
}

}  // namespace

void check_distinct_outputs(const std::vector<NamedPath>& outputs,
                            const std::vector<NamedPath>& inputs) {
  std::vector<const NamedPath*> outs, ins;
  for (const NamedPath& o : outputs)
    if (!o.path.empty()) outs.push_back(&o);
  for (const NamedPath& i : inputs)
    if (!i.path.empty()) ins.push_back(&i);
  auto overlap = [](const NamedPath& a, const NamedPath& b) {
    for (const fs::path& x : files_of(a.path, a.companions))
      for (const fs::path& y : files_of(b.path, b.companions))
        if (same_file(x, y)) return true;
    return false;
  };
  for (size_t i = 0; i < outs.size(); ++i) {
    const fs::path folder = identity_of(outs[i]->path);
    const bool is_folder = is_folder_output(outs[i]->path);
    for (size_t j = 0; j < outs.size(); ++j) {
      if (j > i && overlap(*outs[i], *outs[j]))
        throw InputError(named(*outs[j]) + " and " + named(*outs[i]) +
                         " would write the same file: give each output its own path");
      if (j != i && is_folder && inside(folder, identity_of(outs[j]->path)))
        throw InputError(named(*outs[j]) + " is inside the folder " + named(*outs[i]) +
                         ", which is replaced as a whole: write it elsewhere");
    }
    for (const NamedPath* in : ins) {
      if (overlap(*outs[i], *in))
        throw InputError(named(*outs[i]) + " is the input " + named(*in) +
                         ": writing it would replace the input; give another output path");
      if (is_folder && inside(folder, identity_of(in->path)))
        throw InputError("the input " + named(*in) + " is inside the output folder " +
                         named(*outs[i]) + ", which is replaced as a whole: write elsewhere");
    }
  }
}

// --- signals -------------------------------------------------------------------------------------

void install_output_cleanup_on_signals() {
  struct sigaction action {};
  action.sa_handler = remove_outputs_on_signal;
  sigemptyset(&action.sa_mask);
  const int signals[] = {SIGINT, SIGTERM, SIGHUP};
  for (int s : signals) sigaddset(&action.sa_mask, s);  // one handler at a time
  for (int s : signals) {
    struct sigaction previous {};
    if (::sigaction(s, nullptr, &previous) == 0 && previous.sa_handler == SIG_IGN) continue;
    ::sigaction(s, &action, nullptr);
  }
  struct sigaction ignore {};
  ignore.sa_handler = SIG_IGN;
  sigemptyset(&ignore.sa_mask);
  ::sigaction(SIGXFSZ, &ignore, nullptr);
}

}  // namespace sonoslice
