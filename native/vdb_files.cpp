#include "vdb_files.h"

#include <fcntl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

#include "vdb_writer.h"

namespace ep {

std::runtime_error vdb_path_error(const std::string& path, const std::string& what) {
    return std::runtime_error("vdb file '" + path + "': " + what);
}

// Creates an empty, uniquely named file next to `path` (same directory, so the
// final rename stays on one filesystem and is atomic). O_EXCL makes the name
// ours even if two processes write the same target; mode 0666 lets the umask
// decide permissions as for any ordinary file.
std::string create_temp_file(const std::string& path) {
    static std::atomic<unsigned> counter{0};
    for (int attempt = 0; attempt < 100; ++attempt) {
        std::ostringstream name;
        name << path << ".tmp-" << ::getpid() << "-" << counter.fetch_add(1);
        const std::string tmp = name.str();
        const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
        if (fd >= 0) {
            ::close(fd);
            return tmp;
        }
        if (errno != EEXIST)
            throw vdb_path_error(path,
                                 std::string("cannot create a temporary file next to it: ") + std::strerror(errno));
    }
    throw vdb_path_error(path, "cannot find a free temporary file name next to it");
}

// Flush file data to disk before the rename, so that after a crash the target
// holds either the old file or the complete new one, never an empty file.
void sync_file(const std::string& tmp, const std::string& path) {
    const int fd = ::open(tmp.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0 || ::fsync(fd) != 0) {
        const std::string why = std::strerror(errno);
        if (fd >= 0) ::close(fd);
        throw vdb_path_error(path, "cannot flush the temporary file '" + tmp + "': " + why);
    }
    ::close(fd);
}

// The likely cause of a failed write when the stream did not leave errno set:
// found from the filesystem and the process limits.
std::string likely_cause(const std::string& tmp) {
    struct statvfs fs;
    if (::statvfs(tmp.c_str(), &fs) == 0 && uint64_t(fs.f_bavail) * uint64_t(fs.f_frsize) < (uint64_t(1) << 20))
        return std::strerror(ENOSPC);
    struct rlimit lim;
    struct stat st;
    if (::getrlimit(RLIMIT_FSIZE, &lim) == 0 && lim.rlim_cur != RLIM_INFINITY && ::stat(tmp.c_str(), &st) == 0 &&
        uint64_t(st.st_size) >= uint64_t(lim.rlim_cur))
        return std::string(std::strerror(EFBIG)) + " (the process file-size limit, ulimit -f)";
    return "the data did not reach the disk";
}

uint64_t tree_memory_limit() {
    const uint64_t page = uint64_t(::sysconf(_SC_PAGESIZE));
    uint64_t avail = 0;
    std::ifstream info("/proc/meminfo");
    std::string key;
    uint64_t kb = 0;
    while (info >> key >> kb) {
        if (key == "MemAvailable:") {
            avail = kb * 1024;
            break;
        }
        info.ignore(256, '\n');
    }
    if (avail == 0) avail = uint64_t(std::max(0L, ::sysconf(_SC_AVPHYS_PAGES))) * page;
    rlimit lim{};
    if (::getrlimit(RLIMIT_AS, &lim) == 0 && lim.rlim_cur != RLIM_INFINITY) {
        uint64_t pages = 0;  // the address space in use (/proc/self/statm: size in pages)
        std::ifstream statm("/proc/self/statm");
        statm >> pages;
        const uint64_t used = pages * page;
        avail = std::min<uint64_t>(avail, uint64_t(lim.rlim_cur) > used ? uint64_t(lim.rlim_cur) - used : 0);
    }
    return avail / 4 * 3;
}

namespace {

// What kind of file st describes, for an error message.
const char* file_kind(const struct stat& st) {
    if (S_ISLNK(st.st_mode)) return "a symbolic link (refused wherever it points: the write would replace the link)";
    if (S_ISDIR(st.st_mode)) return "a directory";
    if (S_ISFIFO(st.st_mode)) return "a FIFO";
    if (S_ISSOCK(st.st_mode)) return "a socket";
    if (S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode)) return "a device";
    return "not a regular file";
}

// Throws std::invalid_argument "grids.path = '<path>' <what>".
[[noreturn]] void bad_path(const std::string& path, const std::string& what) {
    throw std::invalid_argument("grids.path = '" + path + "' " + what);
}

// Longest ".tmp-<pid>-<counter>" suffix create_temp_file appends.
constexpr size_t kTempSuffixMax = 5 + 10 + 1 + 10;

}  // namespace

// Refuses a path that exists and is not a regular file (symbolic links included).
void check_target_kind(const std::string& path) {
    struct stat st;
    if (::lstat(path.c_str(), &st) != 0) {
        if (errno == ENOENT) return;
        bad_path(path, std::string("cannot be inspected: ") + std::strerror(errno));
    }
    if (!S_ISREG(st.st_mode))
        bad_path(path, std::string("exists and is ") + file_kind(st) +
                           ": the grid file replaces only a regular file; give a new file name");
}

void check_vdb_path(const std::string& path) {
    if (path.empty()) throw std::invalid_argument("grids.path = '' must name a file");
    if (path.find('\0') != std::string::npos) bad_path(path, "holds a NUL character");
    if (path.size() + kTempSuffixMax >= PATH_MAX)
        bad_path(path.substr(0, 80) + "...", "is " + std::to_string(path.size()) +
                                                 " characters long, beyond the limit PATH_MAX = " +
                                                 std::to_string(PATH_MAX) + " less the temporary file's suffix");
    if (path.back() == '/') bad_path(path, "ends in '/': it must name a file, not a directory");
    const size_t slash = path.rfind('/');
    const std::string dir = slash == std::string::npos ? "." : (slash == 0 ? "/" : path.substr(0, slash));
    const std::string base = slash == std::string::npos ? path : path.substr(slash + 1);
    if (base == "." || base == "..") bad_path(path, "must name a file, not a directory");
    struct stat st;
    if (::stat(dir.c_str(), &st) != 0)
        bad_path(path, "is in the directory '" + dir + "', which cannot be used: " + std::strerror(errno));
    if (!S_ISDIR(st.st_mode)) bad_path(path, "is in '" + dir + "', which is not a directory");
    long name_max = ::pathconf(dir.c_str(), _PC_NAME_MAX);
    if (name_max <= 0) name_max = NAME_MAX;
    if (base.size() + kTempSuffixMax > size_t(name_max))
        bad_path(path, "has a file name of " + std::to_string(base.size()) + " characters; the directory allows " +
                           std::to_string(name_max) + " and the temporary file's suffix needs " +
                           std::to_string(kTempSuffixMax) + " of them: give a shorter name");
    check_target_kind(path);
    // Whether the write can make its temporary file there, tried (the
    // permission bits do not tell root, or a read-only or virtual file system).
    std::string probe;
    try {
        probe = create_temp_file(path);
    } catch (const std::runtime_error&) {
        bad_path(path, "is in the directory '" + dir + "', where no file can be created: " + std::strerror(errno));
    }
    std::remove(probe.c_str());
}

[[noreturn]] void throw_vdb_voxel_size(double voxel_size) {
    std::ostringstream msg;
    msg << "grids.voxel_size = " << voxel_size
        << " is below the smallest voxel OpenVDB can scale to (about 1e-5 scene units): give the scene in a "
           "smaller unit, or a larger voxel";
    throw std::invalid_argument(msg.str());
}

bool vdb_voxel_size_supported(double voxel_size) {
    if (!(voxel_size > 0) || !std::isfinite(voxel_size)) return false;
    // OpenVDB's linear transform of voxel size s is a uniform scale map, which
    // refuses a determinant s s s below 3 Tolerance<double> = 3e-15 in
    // magnitude (openvdb/math/Maps.h, ScaleMap). The same rule here, so that a
    // run checks its voxel size before it starts without loading OpenVDB,
    // which it then loads only to write (vdb_library.h); test_vdb_writer
    // holds the rule to OpenVDB's own answer about the threshold.
    const double determinant = voxel_size * voxel_size * voxel_size;
    return !(std::fabs(determinant) < 3.0 * 1e-15);
}

void check_vdb_voxel_size(double voxel_size) {
    if (!vdb_voxel_size_supported(voxel_size)) throw_vdb_voxel_size(voxel_size);
}

}  // namespace ep
