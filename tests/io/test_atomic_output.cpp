// Writers that cannot lie (docs/conventions.md §6): exclusive, unpredictable
// temporaries; a failed write (file-size limit) leaves the old output byte for byte and no
// temporary; signals remove temporaries; folders are replaced only when they hold sonoslice's own
// images; two outputs, or an output and an input, never share a file.
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>

#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/StackWriter.h"
#include "sonoslice/io/VolumeFile.h"

namespace sonoslice {
namespace {

namespace fs = std::filesystem;

// Every file and folder under `dir`, with the bytes of the files.
std::map<std::string, std::string> snapshot(const fs::path& dir) {
  std::map<std::string, std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    out[fs::relative(e.path(), dir).string()] =
        e.is_regular_file() ? test::read_file_bytes(e.path().string()) : "<folder>";
  return out;
}

std::vector<std::string> entries(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

// A stack of `n` 40×30 float images whose values differ from one image to the next.
void write_test_stack(const std::string& path, int64_t n) {
  StackSpec s;
  s.width = 40;
  s.height = 30;
  s.count = n;
  s.spacing_mm[0] = s.spacing_mm[1] = 0.5;
  s.window = std::make_pair(0.0, 2.0);
  s.poses.assign(size_t(n), Pose::identity());
  auto w = StackWriter::create(path, s);
  for (int64_t i = 0; i < n; ++i) {
    float* image = static_cast<float*>(w->buffer(i, 1));
    // Pseudo-random, so that no format compresses it below the size limits used here.
    uint32_t state = uint32_t(i) * 2654435761u + 1;
    for (int p = 0; p < 40 * 30; ++p) {
      state = state * 1664525u + 1013904223u;
      image[p] = float(state >> 8) / float(1 << 23);
    }
    w->write(i, 1);
  }
  w->commit();
}

// Runs `body` in a child process with a file-size limit, SIGXFSZ ignored (so that a write past
// the limit fails with EFBIG, as under `ulimit -f`); returns the child's exit status and what it
// reported. Exit 0: the write succeeded; 1: FileError (its message in *message); 2: another
// error.
int in_limited_child(rlim_t limit_bytes, const std::function<void()>& body, std::string* message) {
  int pipe_fds[2];
  if (::pipe(pipe_fds) != 0) return -1;
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::close(pipe_fds[0]);
    ::signal(SIGXFSZ, SIG_IGN);
    const rlimit limit{limit_bytes, limit_bytes};
    ::setrlimit(RLIMIT_FSIZE, &limit);
    int code = 0;
    std::string text;
    try {
      body();
    } catch (const FileError& e) {
      code = 1, text = e.what();
    } catch (const std::exception& e) {
      code = 2, text = e.what();
    }
    if (!text.empty() && ::write(pipe_fds[1], text.data(), text.size()) < 0) code = 3;
    ::_exit(code);
  }
  ::close(pipe_fds[1]);
  char buffer[1024];
  for (ssize_t n; (n = ::read(pipe_fds[0], buffer, sizeof buffer)) > 0;)
    message->append(buffer, size_t(n));
  ::close(pipe_fds[0]);
  int status = 0;
  ::waitpid(pid, &status, 0);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
}

TEST(AtomicOutput, TemporariesAreExclusiveAndUnpredictable) {
  test::TempDir dir;
  const std::string path = dir.file("o.npy");
  AtomicFile a(path), b(path);
  EXPECT_NE(a.temp_path(), b.temp_path());
  for (const AtomicFile* f : {&a, &b}) {
    const std::string name = fs::path(f->temp_path()).filename().string();
    EXPECT_EQ(name.rfind(".tmp-sonoslice-", 0), 0u) << name;
    EXPECT_EQ(name.find(std::to_string(::getpid())), std::string::npos) << name;  // no PID
    EXPECT_EQ(fs::path(f->temp_path()).parent_path(), dir.path());                // same filesystem
    EXPECT_TRUE(fs::is_regular_file(fs::symlink_status(f->temp_path())));
    EXPECT_GE(f->fd(), 0);
  }
}

// The old names were .tmp-sonoslice-<pid>-<n>.<name>, opened without O_EXCL: a link planted there
// redirected the write into another file.
TEST(AtomicOutput, PlantedLinksAtTheOldTemporaryNamesAreNotFollowed) {
  test::TempDir dir;
  std::ofstream(dir.file("victim.txt")) << "precious";
  for (int n = 0; n < 8; ++n)
    fs::create_symlink(dir.file("victim.txt"),
                       dir.file(".tmp-sonoslice-" + std::to_string(::getpid()) + "-" +
                                std::to_string(n) + ".o.npy"));
  const std::vector<float> data(24, 1.5f);
  for (int n = 0; n < 3; ++n)
    write_npy(dir.file("o.npy"), PixelType::Float32, {2, 3, 4}, data.data());
  write_text_file(dir.file("o.npy.txt"), "text");
  EXPECT_EQ(test::read_file_bytes(dir.file("victim.txt")), "precious");
  EXPECT_EQ(read_npy(dir.file("o.npy")).shape, (std::vector<int64_t>{2, 3, 4}));
}

// A shape whose byte count overflows once wrote a 102-byte file (the product wrapped to 0): it is
// refused before anything is created, and the old file stays.
TEST(AtomicOutput, NpyShapesThatOverflowAreRefusedBeforeAnythingIsWritten) {
  test::TempDir dir;
  std::ofstream(dir.file("o.npy")) << "old";
  const float one = 1.0f;
  for (const std::vector<int64_t>& shape :
       {std::vector<int64_t>{int64_t(1) << 32, int64_t(1) << 32, 1},
        {int64_t(1) << 62, 2},
        {4, -1}}) {
    try {
      write_npy(dir.file("o.npy"), PixelType::Float32, shape, &one);
      ADD_FAILURE() << "a shape of " << shape[0] << " was taken";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("cannot write '" + dir.file("o.npy") + "': the shape ("),
                std::string::npos)
          << e.what();
    }
  }
  EXPECT_EQ(test::read_file_bytes(dir.file("o.npy")), "old");
  EXPECT_EQ(std::distance(fs::directory_iterator(dir.path()), fs::directory_iterator()), 1);
}

class FailedWrite : public ::testing::TestWithParam<std::string> {};

// A file-size limit stops every format mid-write: FileError naming the output, the old output
// byte for byte, no temporary. Once, .nii, .nii.gz and .mha reported success and
// replaced the old file with a truncated one.
TEST_P(FailedWrite, KeepsTheOldOutputAndNoTemporary) {
  test::TempDir dir;
  const std::string path = dir.file("o" + GetParam());
  write_test_stack(path, 2);
  const auto before = snapshot(dir.path());
  std::string message;
  const int code = in_limited_child(
      1000, [&] { write_test_stack(path, 400); }, &message);
  EXPECT_EQ(code, 1) << message;
  EXPECT_NE(message.find("'" + path + "'"), std::string::npos) << message;
  EXPECT_NE(message.find("file too large"), std::string::npos) << message;
  EXPECT_EQ(message.find(".tmp-sonoslice"), std::string::npos) << message;
  const auto after = snapshot(dir.path());
  EXPECT_EQ(after, before);  // same names (no temporary) and same bytes
}

INSTANTIATE_TEST_SUITE_P(Formats, FailedWrite,
                         ::testing::Values(".nii", ".nii.gz", ".mha", ".mhd", ".nrrd", ".npy",
                                           "_pngs"),
                         [](const auto& info) {
                           std::string name = info.param.substr(1);
                           std::replace(name.begin(), name.end(), '.', '_');
                           return name;
                         });

// Formats of two files (header + data) used to leave the data under its hidden temporary name (and
// a .hdr lost its .img altogether): they are now written in a private folder and moved out.
TEST(AtomicOutput, TwoFileFormatsKeepTheirCompanionUnderItsRealName) {
  test::TempDir dir;
  const Volume v = test::make_volume<int16_t>(test::oblique_grid({7, 6, 5}),
                                              [](const Vec3& p) { return p[0] + 3 * p[1]; });
  for (const char* name : {"a.mhd", "b.nhdr", "c.hdr"}) {
    write_volume(dir.file(name), v);
    const Volume back = read_volume(dir.file(name));
    ASSERT_EQ(back.byte_size(), v.byte_size()) << name;
    EXPECT_EQ(std::memcmp(back.data(), v.data(), v.byte_size()), 0) << name;
  }
  EXPECT_EQ(entries(dir.path()),
            (std::vector<std::string>{"a.mhd", "a.raw", "b.nhdr", "b.raw", "c.hdr", "c.img"}));
}

// ITK writes a .nii.gz as .nii, which sonoslice compresses (at a faster zlib level than ITK's) in
// the same private folder: only the .nii.gz comes out, a gzip file that reads back the same.
TEST(AtomicOutput, NiftiGzIsCompressedWithoutLeavingTheNiiBehind) {
  test::TempDir dir;
  const Volume v = test::make_volume<int16_t>(test::oblique_grid({40, 30, 20}),
                                              [](const Vec3& p) { return p[0] + 3 * p[1]; });
  write_volume(dir.file("a.nii.gz"), v);
  EXPECT_EQ(entries(dir.path()), (std::vector<std::string>{"a.nii.gz"}));
  std::ifstream in(dir.file("a.nii.gz"), std::ios::binary);
  unsigned char magic[2] = {0, 0};
  in.read(reinterpret_cast<char*>(magic), 2);
  EXPECT_EQ(magic[0], 0x1f);
  EXPECT_EQ(magic[1], 0x8b);
  EXPECT_LT(fs::file_size(dir.file("a.nii.gz")), v.byte_size() / 2);  // compressed at all
  const Volume back = read_volume(dir.file("a.nii.gz"));
  ASSERT_EQ(back.byte_size(), v.byte_size());
  EXPECT_EQ(std::memcmp(back.data(), v.data(), v.byte_size()), 0);
  EXPECT_EQ(back.grid().origin_mm, v.grid().origin_mm);
}

TEST(AtomicOutput, WriteErrorsSayWhyInPlainWords) {
  EXPECT_EQ(write_error_message("o.nii", ENOSPC), "cannot write 'o.nii': no space left on device");
  EXPECT_NE(write_error_message("o.nii", EFBIG).find("file too large"), std::string::npos);
  EXPECT_EQ(write_error_message("o.nii", EACCES), "cannot write 'o.nii': permission denied");
  test::TempDir dir;
  EXPECT_EQ(incomplete_write_reason(dir.file("nothing-wrong.nii")), "");
}

// --- folders ---------------------------------------------------------------------------------

TEST(AtomicOutput, ImageFolderReplacedOnlyWhenItHoldsNothingButSonoslicesImages) {
  test::TempDir dir;
  const std::string out = dir.file("pngs");
  write_test_stack(out, 3);
  write_test_stack(out, 2);  // sonoslice's own images: replaced as a whole
  EXPECT_EQ(entries(out),
            (std::vector<std::string>{"img_00000.png", "img_00001.png", "poses.txt"}));

  std::ofstream(out + "/notes.txt") << "mine";
  try {
    write_test_stack(out, 1);
    ADD_FAILURE() << "a folder holding a foreign file was replaced";
  } catch (const FileError& e) {
    EXPECT_NE(std::string(e.what()).find("'notes.txt'"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("'" + out + "'"), std::string::npos) << e.what();
  }
  EXPECT_EQ(test::read_file_bytes(out + "/notes.txt"), "mine");
  EXPECT_EQ(entries(out).size(), 4u);
  EXPECT_EQ(entries(dir.path()), (std::vector<std::string>{"pngs"}));  // no temporary

  // A folder named img_00000.png is not an image: not ours either.
  fs::remove(out + "/notes.txt");
  fs::create_directory(out + "/img_00007.png");
  EXPECT_THROW(write_test_stack(out, 1), FileError);
  EXPECT_TRUE(fs::is_directory(out + "/img_00007.png"));

  // An empty folder is replaced; a link to a folder of ours replaces the folder it names.
  fs::create_directory(dir.file("empty"));
  write_test_stack(dir.file("empty"), 1);
  EXPECT_TRUE(fs::exists(dir.file("empty/img_00000.png")));
  fs::create_directory_symlink(dir.file("empty"), dir.file("link"));
  write_test_stack(dir.file("link"), 2);
  EXPECT_TRUE(fs::is_symlink(dir.file("link")));
  EXPECT_TRUE(fs::exists(dir.file("empty/img_00001.png")));
}

TEST(AtomicOutput, ImageFolderNeverTheCurrentFolderItsParentsOrTheRoot) {
  test::TempDir dir;
  fs::create_directories(dir.file("a/b"));
  const fs::path cwd = fs::current_path();
  fs::current_path(dir.file("a/b"));
  std::string errors;
  for (const char* path : {".", "..", "./", "../b", "/"}) {
    try {
      check_output_path(path, true);
      errors += std::string(path) + " accepted; ";
    } catch (const FileError&) {
    }
  }
  fs::current_path(cwd);
  EXPECT_EQ(errors, "");
  EXPECT_TRUE(fs::is_directory(dir.file("a/b")));
}

// --- distinct outputs --------------------------------------------------------------------------

std::string distinct_error(const std::vector<NamedPath>& outputs,
                           const std::vector<NamedPath>& inputs = {}) {
  try {
    check_distinct_outputs(outputs, inputs);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(AtomicOutput, DistinctOutputsAreDistinctFiles) {
  test::TempDir dir;
  fs::create_directory(dir.file("d"));
  std::ofstream(dir.file("ct.nii.gz")) << "ct";
  fs::create_hard_link(dir.file("ct.nii.gz"), dir.file("hard.nii.gz"));
  fs::create_symlink(dir.file("ct.nii.gz"), dir.file("soft.nii.gz"));
  const std::string o = dir.file("o.npy");
  EXPECT_EQ(distinct_error({{"--out", o}, {"--mask", dir.file("m.png")}, {"--colors", ""}}), "");
  EXPECT_NE(distinct_error({{"--out", o}, {"--mask", o}}).find("--mask '" + o + "' and --out"),
            std::string::npos);
  EXPECT_NE(distinct_error({{"--out", o}, {"--weights", dir.file("d/../o.npy")}}), "");
  EXPECT_NE(distinct_error({{"--out", o}, {"--weights", dir.file("o.NPY")}}), "");  // o.json
  EXPECT_NE(distinct_error({{"--out", dir.file("v.mhd")}, {"--weights", dir.file("v.nhdr")}}),
            "");  // both write v.raw
  EXPECT_NE(distinct_error({{"--out", dir.file("v.hdr")}, {"--weights", dir.file("v.img")}}), "");
  // An output that is an input: by name, through a link, through a hard link.
  for (const char* name : {"ct.nii.gz", "soft.nii.gz", "hard.nii.gz"}) {
    const std::string e =
        distinct_error({{"--out", dir.file(name)}}, {{"--volume", dir.file("ct.nii.gz")}});
    EXPECT_NE(e.find("is the input --volume"), std::string::npos) << name << ": " << e;
  }
  // A folder output is replaced as a whole: nothing else may live in it.
  EXPECT_NE(distinct_error({{"--out", dir.file("d")}, {"--mask", dir.file("d/m.png")}}), "");
  EXPECT_NE(distinct_error({{"--out", dir.path().string()}}, {{"--volume", dir.file("ct.nii.gz")}}),
            "");
  EXPECT_EQ(distinct_error({{"--out", dir.file("d")}}, {{"--volume", dir.file("ct.nii.gz")}}), "");
}

// --- signals -----------------------------------------------------------------------------------

// A child that holds live temporaries of every kind waits for a signal.
pid_t child_with_live_temporaries(const test::TempDir& dir, bool ignore_sigint_first) {
  int ready[2];
  if (::pipe(ready) != 0) return -1;
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::close(ready[0]);
    if (ignore_sigint_first) ::signal(SIGINT, SIG_IGN);
    install_output_cleanup_on_signals();
    try {
      NpyWriter npy(dir.file("o.npy"), PixelType::Float32, {1000});
      npy.write(std::vector<float>(10).data(), 40);
      AtomicFile staged(dir.file("o.nii.gz"), OutputKind::Staged);
      std::ofstream(staged.temp_path()) << "partial";
      AtomicFile folder(dir.file("pngs"), OutputKind::Folder);
      std::ofstream(folder.temp_path() + "/img_00000.png") << "partial";
      std::ofstream(folder.temp_path() + "/img_00001.png") << "partial";
      if (::write(ready[1], "r", 1) != 1) ::_exit(3);
      for (;;) ::pause();
    } catch (...) {
      ::_exit(2);
    }
  }
  ::close(ready[1]);
  char c;
  const bool ok = ::read(ready[0], &c, 1) == 1;
  ::close(ready[0]);
  return ok ? pid : -1;
}

TEST(AtomicOutput, SignalsRemoveLiveTemporariesAndStillEndTheProcess) {
  for (int sig : {SIGTERM, SIGINT, SIGHUP}) {
    test::TempDir dir;
    std::ofstream(dir.file("o.npy")) << "previous good data";
    const pid_t pid = child_with_live_temporaries(dir, false);
    ASSERT_GT(pid, 0);
    EXPECT_GT(entries(dir.path()).size(), 1u);  // the temporaries exist while it runs
    ::kill(pid, sig);
    int status = 0;
    ::waitpid(pid, &status, 0);
    EXPECT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == sig) << strsignal(sig);
    EXPECT_EQ(entries(dir.path()), (std::vector<std::string>{"o.npy"})) << strsignal(sig);
    EXPECT_EQ(test::read_file_bytes(dir.file("o.npy")), "previous good data");
  }
}

TEST(AtomicOutput, SignalIgnoredOnEntryStaysIgnored) {
  test::TempDir dir;
  const pid_t pid = child_with_live_temporaries(dir, /*ignore_sigint_first=*/true);
  ASSERT_GT(pid, 0);
  ::kill(pid, SIGINT);  // nohup-style: ignored, the child runs on
  ::usleep(200 * 1000);
  int status = 0;
  EXPECT_EQ(::waitpid(pid, &status, WNOHANG), 0);
  ::kill(pid, SIGTERM);
  ::waitpid(pid, &status, 0);
  EXPECT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGTERM);
  EXPECT_TRUE(entries(dir.path()).empty());
}

}  // namespace
}  // namespace sonoslice
