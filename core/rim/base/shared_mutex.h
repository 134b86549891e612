// A reader-writer lock on which a waiting writer goes before new readers.
//
// std::shared_mutex on glibc is a default pthread rwlock, which prefers readers: while any reader
// holds it, new readers get in, and a writer waits for a moment with no reader at all. The map's
// readers (a dashboard's meshing, one block at a time; a planner's queries, one chunk at a time)
// release and take the lock again back to back, so the trainer, which takes it exclusively once
// per iteration, waited through whole rounds of them while its worker threads sat idle. Here a
// waiting writer blocks new readers: it waits for the readers already in (one block or one chunk),
// then the readers wait for one iteration.
//
// The price: a thread must not take the shared lock a second time while it holds it (a writer
// waiting in between would deadlock it). Mapper never does.
#pragma once

#include <pthread.h>

#include <cerrno>
#include <system_error>

namespace rim {

class WriterFirstSharedMutex {
 public:
  WriterFirstSharedMutex() {
    pthread_rwlockattr_t attr;
    pthread_rwlockattr_init(&attr);
#if defined(__GLIBC__)
    pthread_rwlockattr_setkind_np(&attr, PTHREAD_RWLOCK_PREFER_WRITER_NONRECURSIVE_NP);
#endif
    const int rc = pthread_rwlock_init(&lock_, &attr);
    pthread_rwlockattr_destroy(&attr);
    if (rc != 0) throw std::system_error(rc, std::generic_category(), "pthread_rwlock_init");
  }
  ~WriterFirstSharedMutex() { pthread_rwlock_destroy(&lock_); }
  WriterFirstSharedMutex(const WriterFirstSharedMutex&) = delete;
  WriterFirstSharedMutex& operator=(const WriterFirstSharedMutex&) = delete;

  // Lockable and SharedLockable, for std::unique_lock and std::shared_lock.
  void lock() { Check(pthread_rwlock_wrlock(&lock_), "pthread_rwlock_wrlock"); }
  bool try_lock() { return pthread_rwlock_trywrlock(&lock_) == 0; }
  void unlock() { pthread_rwlock_unlock(&lock_); }
  void lock_shared() {
    int rc;
    // EAGAIN: too many readers at once (not reachable with a handful of threads); try again.
    while ((rc = pthread_rwlock_rdlock(&lock_)) == EAGAIN) {
    }
    Check(rc, "pthread_rwlock_rdlock");
  }
  bool try_lock_shared() { return pthread_rwlock_tryrdlock(&lock_) == 0; }
  void unlock_shared() { pthread_rwlock_unlock(&lock_); }

 private:
  static void Check(int rc, const char* what) {
    // EDEADLK: the calling thread already holds the lock, a bug in the caller.
    if (rc != 0) throw std::system_error(rc, std::generic_category(), what);
  }
  pthread_rwlock_t lock_;
};

}  // namespace rim
