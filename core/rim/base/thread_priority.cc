#include "rim/base/thread_priority.h"

#include <algorithm>

#if defined(__linux__)
#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <cerrno>
#endif

namespace rim {

void NameThisThread(const std::string& name) {
#if defined(__linux__)
  pthread_setname_np(pthread_self(), name.substr(0, 15).c_str());
#else
  (void)name;
#endif
}

int ThisThreadNice() {
#if defined(__linux__)
  errno = 0;
  const int nice = getpriority(PRIO_PROCESS, id_t(syscall(SYS_gettid)));
  return errno == 0 ? nice : 0;
#else
  return 0;
#endif
}

bool LowerThisThreadPriority(int nice) {
#if defined(__linux__)
  nice = std::clamp(nice, 0, 19);
  if (ThisThreadNice() >= nice) return true;
  // On Linux, PRIO_PROCESS with a thread id sets that thread alone.
  return setpriority(PRIO_PROCESS, id_t(syscall(SYS_gettid)), nice) == 0;
#else
  (void)nice;
  return true;
#endif
}

}  // namespace rim
