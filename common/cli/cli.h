// One flags layer for every Exoview binary, on CLI11. The conventions every binary follows:
//   --key=value and --key value both work; --help prints usage and exits 0 without running
//   anything; --version prints the version; an unknown flag or a bad value is an error that names
//   it and exits 2 (nothing runs).
// Usage:
//   CLI::App app{"What the binary does.", "exoview_foo"};
//   exo::cli::Setup(app);
//   app.add_option("--frames", frames, "frames to read")->check(CLI::PositiveNumber);
//   if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
#pragma once

#include <optional>
#include <string>

#include "CLI/CLI.hpp"

namespace exo::cli {

// The project's version string ("0.1.0 (git abc1234)").
std::string Version();

// Applies the conventions to an app: --version, no extras, options sorted as added, --help
// shows each option's default (options added after Setup).
void Setup(CLI::App& app);

// Parses argv. Returns nothing when the program should go on; otherwise the exit code to return
// from main: 0 after --help / --version (printed to stdout), 2 after a parse error (printed to
// stderr with the flag it names and a hint to run --help).
std::optional<int> Parse(CLI::App& app, int argc, const char* const* argv);

}  // namespace exo::cli
