// Names and OS priorities of threads (docs/service.md, "Sharing the cores"). The server runs
// latency-bound work (queries, ingest, acks) at the normal priority and throughput work
// (training, distance-field refreshes, meshing for watchers) at a lower one, so that on a small
// machine a planner's batch is answered at once instead of queueing behind a training iteration
// for the cores. Linux gives every thread its own nice value; elsewhere these do nothing.
#pragma once

#include <string>

namespace rim {

// Names the calling thread (top -H, perf, gdb show it); names are cut to 15 characters.
void NameThisThread(const std::string& name);

// The calling thread's nice value (-20..19; 0 where unknown).
int ThisThreadNice();

// Lowers the calling thread's priority to nice `nice` (clamped to 0..19) when it runs at a higher
// one; never raises it (that needs privileges). Returns false when the OS refused.
bool LowerThisThreadPriority(int nice);

}  // namespace rim
