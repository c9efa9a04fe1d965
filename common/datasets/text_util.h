// Internal helpers of common/datasets: reading small text files and parsing numbers with
// error messages that name the file and line.
#pragma once

#include <array>
#include <string>
#include "absl/strings/string_view.h"
#include <vector>

#include "common/status.h"

namespace exo::datasets_internal {

// Whole file as text. NotFound naming the path if it cannot be opened.
absl::StatusOr<std::string> ReadTextFile(const std::string& path);

struct TextLine {
  int number = 0;                       // 1-based line number in the file
  std::vector<absl::string_view> tokens;  // whitespace-separated (views into the text)
};
// Non-empty lines not starting with '#', split on whitespace (commas also separate).
std::vector<TextLine> TokenizeLines(absl::string_view text);

// Parses tokens[first, first+count) as doubles. Error names path:line.
absl::Status ParseDoubles(const TextLine& line, size_t first, size_t count, double* out,
                          const std::string& path);

bool FileExists(const std::string& path);

// A 4x4 matrix file (16 numbers, row-major, any line breaks): 7-Scenes poses, ScanNet
// intrinsics/poses. Errors name the file.
absl::StatusOr<std::array<double, 16>> ReadMatrix4x4(const std::string& path);

}  // namespace exo::datasets_internal
