#include "vdb_library.h"

#include <dlfcn.h>

#include <exception>
#include <mutex>
#include <stdexcept>

namespace ep {

namespace {

using Entry = const VdbApi* (*)();

// The folder of the object (the Python module, or a program) this code is in.
std::string own_folder() {
    Dl_info info{};
    if (!::dladdr(reinterpret_cast<void*>(&vdb_api), &info) || !info.dli_fname) return ".";
    const std::string self = info.dli_fname;
    const size_t slash = self.rfind('/');
    return slash == std::string::npos ? "." : (slash == 0 ? "/" : self.substr(0, slash));
}

const VdbApi* load() {
    std::string where = "the program";
    Entry entry = reinterpret_cast<Entry>(::dlsym(RTLD_DEFAULT, kVdbEntry));
    if (!entry) {
        where = own_folder() + "/" + kVdbLibrary;
        // Kept for the life of the process: its functions may be called at any time.
        void* handle = ::dlopen(where.c_str(), RTLD_NOW | RTLD_LOCAL);
        if (!handle) {
            const char* why = ::dlerror();
            throw std::runtime_error("grids: the .vdb writer library '" + where + "' cannot be loaded (" +
                                     (why ? why : "no reason given") + "): reinstall endophoton");
        }
        entry = reinterpret_cast<Entry>(::dlsym(handle, kVdbEntry));
        if (!entry)
            throw std::runtime_error("grids: '" + where + "' is not the .vdb writer library (no " + kVdbEntry +
                                     "): reinstall endophoton");
    }
    const VdbApi* api = entry();
    if (!api || api->abi != kVdbAbi)
        throw std::runtime_error("grids: the .vdb writer library in " + where +
                                 " was built from other sources than the engine: reinstall endophoton");
    return api;
}

}  // namespace

const VdbApi& vdb_api() {
    static std::once_flag once;
    static const VdbApi* api = nullptr;
    static std::exception_ptr error;
    std::call_once(once, [] {
        try {
            api = load();
        } catch (...) {
            error = std::current_exception();
        }
    });
    if (error) std::rethrow_exception(error);
    return *api;
}

std::vector<double> write_vdb(const std::string& path, const std::vector<GridOutput>& grids,
                              const std::map<std::string, std::string>& metadata, int threads,
                              uint64_t max_tree_bytes) {
    return vdb_api().write(path, grids, metadata, threads, max_tree_bytes);
}

std::vector<std::string> vdb_grid_names(const std::string& path) { return vdb_api().grid_names(path); }

void ensure_openvdb_initialized() { vdb_api().initialize(); }

}  // namespace ep
