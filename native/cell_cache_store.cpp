#include "cell_cache_store.h"

#include <sys/mman.h>

#include <algorithm>
#include <new>
#include <type_traits>

#include "triangle_cache.h"

namespace ep {

void CellCacheStore::reset(size_t cells) {
    release();
    cells_ = cells;
    cell_block_bytes_.reset(block(cells * sizeof(std::atomic<CellBlock*>)));
    cell_blocks_ = reinterpret_cast<std::atomic<CellBlock*>*>(cell_block_bytes_.get());
    for (size_t i = 0; i < cells; ++i) new (&cell_blocks_[i]) std::atomic<CellBlock*>(nullptr);
}

std::atomic<TriangleCache*>* CellCacheStore::slot(size_t cell, int cube, Cursor& cursor) const {
    CellBlock* b = cell_blocks_[cell].load(std::memory_order_acquire);
    if (!b) {
        if (full()) return nullptr;
        // In the store too, beside the caches (huge pages: block).
        CellBlock* made = new (allocate(sizeof(CellBlock), cursor)) CellBlock();
        if (cell_blocks_[cell].compare_exchange_strong(b, made, std::memory_order_acq_rel))
            b = made;  // else another thread was first; `made` stays unused in the store
    }
    return &b->cube[cube];
}

uint64_t CellCacheStore::new_id() {
    static std::atomic<uint64_t> last{0};
    return ++last;
}

unsigned char* CellCacheStore::block(size_t bytes) {
    // Aligned to a cache line (TriangleCache::kFrozenAlign) at least; a block
    // of a huge page or more to one, and advised onto huge pages (THP in its
    // "madvise" mode, Debian's default; elsewhere the advice changes nothing).
    const size_t align = bytes >= kHugePage ? kHugePage : TriangleCache::kFrozenAlign;
    bytes = std::max(align, (bytes + align - 1) / align * align);  // never 0 (an empty grid's slots)
    void* p = std::aligned_alloc(align, bytes);
    if (!p) throw std::bad_alloc();
    if (align == kHugePage) madvise(p, bytes, MADV_HUGEPAGE);
    return static_cast<unsigned char*>(p);
}

void* CellCacheStore::allocate(size_t bytes, Cursor& cursor) const {
    // Blocks start on a cache line (TriangleCache::kFrozenAlign): a frozen
    // cache's members that a hop reads are then one line, its planes next.
    constexpr size_t kAlign = TriangleCache::kFrozenAlign;
    static_assert(alignof(TriangleCache) <= kAlign, "frozen caches need a finer store");
    bytes = (bytes + kAlign - 1) / kAlign * kAlign;
    if (cursor.store != id_ || cursor.left < bytes) {
        // The rest of the thread's last chunk (of this store or another) stays
        // unused. Small chunks while the store is small (a small scene's store
        // stays small), huge pages once it holds one.
        const size_t chunk = this->bytes() >= kHugePage ? kHugePage : kSmallChunk;
        const size_t size = std::max(chunk, bytes);
        std::lock_guard<std::mutex> lock(mutex_);
        chunks_.emplace_back(block(size));
        bytes_.fetch_add(size, std::memory_order_relaxed);
        cursor = Cursor{id_, chunks_.back().get(), size};
    }
    void* p = cursor.next;
    cursor.next += bytes;
    cursor.left -= bytes;
    return p;
}

void CellCacheStore::release() {
    // The frozen caches and the cells' blocks live in the chunks and need no
    // destructor: freeing the chunks frees them.
    static_assert(std::is_trivially_destructible<TriangleCache>::value, "frozen caches are not destroyed");
    static_assert(std::is_trivially_destructible<CellBlock>::value, "cell blocks are not destroyed");
    if (!cell_blocks_) return;
    cell_blocks_ = nullptr;
    cell_block_bytes_.reset();
    chunks_.clear();
    id_ = new_id();  // no thread's cursor bumps through the freed chunks again
    bytes_.store(0, std::memory_order_relaxed);
}

}  // namespace ep
