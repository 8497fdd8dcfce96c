// Where the scene's per-cube triangle caches live (Scene::cell_cache, issue
// 11): per grid cell a block of kCellSplit^3 cache slots, both levels made on
// first use (the grid of a large scene has up to 128^3 cells, few of them
// ever visited), and the store the blocks and the frozen caches
// (TriangleCache::freeze) are allocated from, with its byte budget. What a
// cache holds is the scene's business; this is the memory it lives in.
#pragma once
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <vector>

namespace ep {

class TriangleCache;

class CellCacheStore {
  public:
    // Every grid cell is split into kCellSplit^3 cubes, one cache slot each.
    // Measured best on colon_polyp (docs/numerics.md): 2 gives cubes too
    // crowded with triangles, 4 more hops and builds.
    static constexpr int kCellSplit = 3;
    static constexpr size_t kDefaultCapBytes = size_t(1) << 29;  // 512 MiB
    // The store grows by chunks of 64 KiB until it holds a huge page, then by
    // huge pages (block).
    static constexpr size_t kSmallChunk = size_t(1) << 16, kHugePage = size_t(1) << 21;

    // A thread's place in its chunk: plain data in a thread_local, valid for
    // the store whose id it names (0: none).
    struct Cursor {
        uint64_t store = 0;
        unsigned char* next = nullptr;
        size_t left = 0;
    };

    CellCacheStore() = default;
    CellCacheStore(const CellCacheStore&) = delete;
    CellCacheStore& operator=(const CellCacheStore&) = delete;
    ~CellCacheStore() { release(); }

    // Empties the store (a thread's cursor into it is then stale: a new id)
    // and makes `cells` empty level-1 slots.
    void reset(size_t cells);
    // The cache of cube `cube` of cell `cell` if it is built, else null:
    // inline, for the interior steps' loop (transport.cpp).
    const TriangleCache* built(size_t cell, int cube) const {
        const CellBlock* block = cell_blocks_[cell].load(std::memory_order_acquire);
        return block ? block->cube[cube].load(std::memory_order_acquire) : nullptr;
    }
    // The slot of cube `cube` of cell `cell`, its cell's block made on first
    // use (any thread; the first one's block is kept), or null when the block
    // is not made yet and the store is full.
    std::atomic<TriangleCache*>* slot(size_t cell, int cube, Cursor& cursor) const;
    // `bytes` of the store, on a cache line (TriangleCache::kFrozenAlign),
    // through the thread's `cursor`: a lock only for a new chunk.
    void* allocate(size_t bytes, Cursor& cursor) const;

    // The store's size and budget in bytes (cell blocks and caches together).
    size_t bytes() const { return bytes_.load(std::memory_order_relaxed); }
    size_t cap_bytes() const { return cap_.load(std::memory_order_relaxed); }
    void set_cap_bytes(size_t bytes) { cap_.store(bytes, std::memory_order_relaxed); }
    bool full() const { return bytes() >= cap_bytes(); }

  private:
    struct FreeBlock {
        void operator()(unsigned char* p) const { std::free(p); }
    };
    struct CellBlock {
        std::atomic<TriangleCache*> cube[kCellSplit * kCellSplit * kCellSplit] = {};
    };
    // The level-1 slots and the store's chunks are on huge pages once they
    // are that large (block): a hop reads a cell's slot and the cube's
    // cache, spread over the store, and with 4 KiB pages it missed the TLB
    // too (AMD EPYC: colon_polyp ~1.16x packets/s; Intel Xeon: no change).
    static unsigned char* block(size_t bytes);
    static uint64_t new_id();
    void release();

    size_t cells_ = 0;
    std::unique_ptr<unsigned char, FreeBlock> cell_block_bytes_;
    std::atomic<CellBlock*>* cell_blocks_ = nullptr;  // cells_ slots in cell_block_bytes_
    // Chunks the store owns, each thread bumping through one of its own, so a
    // build takes the lock only for a new chunk (a malloc per cube cost ~450
    // instructions of its ~4k, a lock on every build ~70; callgrind).
    mutable std::mutex mutex_;
    mutable std::vector<std::unique_ptr<unsigned char, FreeBlock>> chunks_;
    mutable std::atomic<size_t> bytes_{0};  // the chunks allocated (cell blocks and caches)
    std::atomic<size_t> cap_{kDefaultCapBytes};
    uint64_t id_ = new_id();  // unique per store and filling (release renews it)
};

}  // namespace ep
