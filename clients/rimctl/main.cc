// rimctl: the command-line client of rim_server (DESIGN.md §5.5, docs/clients.md).
#include <iostream>

#include "rimctl/commands.h"

int main(int argc, char** argv) { return rim::rimctl::RunRimctl(argc, argv, std::cout, std::cerr); }
