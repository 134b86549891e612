// rim_sim: synthetic datasets with ground truth. See sim/sim.h for the command line.
#include <iostream>

#include "sim/sim.h"

int main(int argc, char** argv) { return rim::sim::RunSimCli(argc, argv, std::cout, std::cerr); }
