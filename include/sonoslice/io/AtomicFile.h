#pragma once
/// @file Outputs that cannot lie (docs/conventions.md §6). Everything sonoslice writes goes to a
/// temporary in the destination's folder, created exclusively (O_EXCL, never through a link) under
/// an unpredictable name, is checked complete and flushed to disk, and only then renamed over the
/// destination. A failure removes the temporary and leaves whatever was at the destination
/// untouched; once install_output_cleanup_on_signals() has run, so do SIGINT, SIGTERM and SIGHUP.
#include <cstddef>
#include <memory>
#include <string>
#include <vector>

namespace sonoslice {

/// What an AtomicFile stages.
enum class OutputKind {
  /// One file, created with O_EXCL under a random name beside the destination: write through
  /// fd(), or open temp_path() by name.
  File,
  /// A private (mode 0700) temporary folder beside the destination in which a writer that opens
  /// files by name (ITK) creates the output under its final name, with any companion file it
  /// writes (a .mhd's .raw, a .hdr's .img). Nobody else can plant a link in that folder.
  /// commit() moves the companions, then the named file.
  Staged,
  /// A folder of images (a PNG stack): built under a random name and renamed into place. An
  /// existing folder at the destination is replaced only when it holds nothing but files
  /// sonoslice writes into such folders (img_NNNNN.png, poses.txt); otherwise FileError naming
  /// it, before anything is written.
  Folder,
};

class AtomicFile {
 public:
  /// Checks the destination (check_output_path) and creates the temporary; FileError naming
  /// `path` when either fails.
  explicit AtomicFile(std::string path, OutputKind kind = OutputKind::File);
  ~AtomicFile();  ///< removes the temporary when commit() was not reached
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  /// File: the temporary file; Staged: the final file name inside the private folder; Folder:
  /// the temporary folder.
  const std::string& temp_path() const { return temp_path_; }
  const std::string& path() const { return path_; }
  /// File: the temporary, open for writing (closed by commit()); -1 for the other kinds.
  int fd() const { return fd_; }

  /// The part of commit() where a full disk shows: flushes the temporary to disk (fsync) and
  /// closes it, both checked. FileError naming path() on failure.
  void prepare();
  /// prepare() when it has not run, then renames the temporary over the destination. FileError
  /// naming path() on any failure, the destination then untouched.
  void commit();

 private:
  void discard() noexcept;

  std::string path_;       // as the caller named it (messages)
  std::string target_;     // where the output goes (a Folder's is absolute and normalised)
  std::string temp_;       // the temporary: file, private folder or image folder
  std::string temp_path_;  // what the writer writes to
  OutputKind kind_;
  int fd_ = -1;
  int slot_ = -1;  // the signal-cleanup registry entry
  bool prepared_ = false, committed_ = false;
  std::vector<std::string> staged_;  // Staged: the files to move out, the named one last
};

/// Outputs of one run that go into place together: commit() prepares every one (flush and
/// close, where a full disk shows), then renames them all. A failure before the renames leaves
/// every destination as it was; destroying the set uncommitted discards the temporaries. (The
/// renames themselves do not fail short of the folder changing under the run.)
class OutputSet {
 public:
  void add(std::unique_ptr<AtomicFile> file);
  void commit();

 private:
  std::vector<std::unique_ptr<AtomicFile>> files_;
};

/// Writes all `n` bytes to `fd` (retrying short writes and EINTR); FileError naming `path` and
/// the reason ("no space left on device", "file too large", ...) otherwise.
void write_fully(int fd, const void* data, size_t n, const std::string& path);

/// Why a write or close failed, in plain words ("no space left on device") for its errno.
std::string write_error_reason(int error_number);
/// "cannot write '<path>': <write_error_reason>".
std::string write_error_message(const std::string& path, int error_number);

/// Why a file that a library wrote (ITK, which does not always say) came out incomplete: the
/// filesystem is full, the file-size limit (ulimit -f) was reached, or "" when neither explains it.
std::string incomplete_write_reason(const std::string& written_file);

/// Writes a small text file atomically; with `together`, leaves it to that set's commit().
void write_text_file(const std::string& path, const std::string& text,
                     OutputSet* together = nullptr);

/// Throws FileError when `path` could not be created as an output: its folder missing or not
/// writable, `path` an existing folder where a file is expected (or a file where a folder is).
/// For a folder output also when the folder holds anything sonoslice did not write, is the
/// current folder or one of its parents, or is '/'.
void check_output_path(const std::string& path, bool directory = false);

/// Free bytes on the filesystem that holds `path`'s directory.
unsigned long long free_disk_bytes(const std::string& path);

/// A path a command reads or writes, with the flag that named it (for messages).
struct NamedPath {
  std::string flag, path;
  /// Whether the format's companion files count (a .npy volume's .json geometry sidecar, a
  /// .mhd's .raw); false for a file that has none, such as a .npy of poses.
  bool companions = true;
};

/// Refuses (InputError, naming both flags and the path) two outputs that would write the same
/// file, an output that would overwrite an input, and an output or input inside a folder output
/// (which is replaced as a whole). Paths are compared after normalising (absolute, symbolic links
/// resolved, same file by inode when it exists), including the files a format writes beside the
/// named one (a .npy's .json sidecar, a .mhd's .raw, a .hdr's .img). Empty paths are skipped.
void check_distinct_outputs(const std::vector<NamedPath>& outputs,
                            const std::vector<NamedPath>& inputs);

/// Installs handlers for SIGINT, SIGTERM and SIGHUP that remove every live temporary (and put
/// back a folder moved aside during a replacement), then let the signal end the process as it
/// would have; signals ignored on entry (nohup) stay ignored. Also ignores SIGXFSZ, so that a
/// file-size limit (ulimit -f) turns into a write error that is reported and cleaned up rather
/// than a kill that leaves the temporary. For programs (the CLI calls it first thing in main);
/// a library never installs signal handlers by itself.
void install_output_cleanup_on_signals();

}  // namespace sonoslice
