// Runs a command-line tool (e.g. rimctl) as a child process and captures what it prints, for
// tests that check a binary the way a script would use it.
#pragma once

#include <chrono>
#include <string>
#include <vector>

namespace rim::testing_support {

struct ProcessResult {
  int exit_code = -1;  // -1 when it died from a signal, was killed at the timeout or never ran
  std::string out;     // stdout
  std::string err;     // stderr
  bool timed_out = false;
};

// Runs argv[0] (a path) with the arguments argv[1..], feeding `stdin_data` to its stdin, and
// waits for it to exit; SIGKILL after `timeout`.
ProcessResult RunProcess(const std::vector<std::string>& argv, const std::string& stdin_data = "",
                         std::chrono::seconds timeout = std::chrono::seconds(120));

}  // namespace rim::testing_support
