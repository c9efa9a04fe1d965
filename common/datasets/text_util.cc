#include "common/datasets/text_util.h"

#include <filesystem>
#include <fstream>
#include <sstream>

#include "absl/strings/numbers.h"
#include "absl/strings/str_split.h"

namespace exo::datasets_internal {

absl::StatusOr<std::string> ReadTextFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open ", path));
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::vector<TextLine> TokenizeLines(absl::string_view text) {
  std::vector<TextLine> lines;
  int number = 0;
  for (absl::string_view raw : absl::StrSplit(text, '\n')) {
    ++number;
    TextLine line;
    line.number = number;
    for (absl::string_view tok : absl::StrSplit(raw, absl::ByAnyChar(" \t\r,"), absl::SkipEmpty()))
      line.tokens.push_back(tok);
    if (line.tokens.empty() || line.tokens[0].front() == '#') continue;
    lines.push_back(std::move(line));
  }
  return lines;
}

absl::Status ParseDoubles(const TextLine& line, size_t first, size_t count, double* out,
                          const std::string& path) {
  if (line.tokens.size() < first + count)
    return absl::InvalidArgumentError(absl::StrCat(path, ":", line.number, ": expected ",
                                                   first + count, " fields, got ",
                                                   line.tokens.size()));
  for (size_t i = 0; i < count; ++i)
    if (!absl::SimpleAtod(line.tokens[first + i], &out[i]))
      return absl::InvalidArgumentError(absl::StrCat(path, ":", line.number, ": '",
                                                     line.tokens[first + i],
                                                     "' is not a number"));
  return absl::OkStatus();
}

bool FileExists(const std::string& path) {
  std::error_code ec;
  return std::filesystem::is_regular_file(path, ec);
}

absl::StatusOr<std::array<double, 16>> ReadMatrix4x4(const std::string& path) {
  EXO_ASSIGN_OR_RETURN(std::string text, ReadTextFile(path));
  std::array<double, 16> m{};
  size_t k = 0;
  for (const auto& line : TokenizeLines(text)) {
    if (k + line.tokens.size() > 16)
      return absl::InvalidArgumentError(absl::StrCat(path, ": more than 16 numbers"));
    EXO_RETURN_IF_ERROR(ParseDoubles(line, 0, line.tokens.size(), m.data() + k, path));
    k += line.tokens.size();
  }
  if (k != 16)
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": expected a 4x4 matrix, got ", k, " numbers"));
  return m;
}

}  // namespace exo::datasets_internal
