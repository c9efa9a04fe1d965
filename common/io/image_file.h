// Image files on disk: colour (RGB8 JPEG/PNG) and 16-bit depth PNG, plus raw byte files.
// Colour is RGB in memory; OpenCV's BGR order is converted here, at the file boundary. JPEG goes
// through common/io/jpeg.h (TurboJPEG, strict: truncated = error); PNG through OpenCV.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "common/image.h"
#include "common/status.h"

namespace exo {

absl::StatusOr<std::vector<uint8_t>> ReadFileBytes(const std::string& path);
absl::Status WriteFileBytes(const std::string& path, std::span<const uint8_t> bytes);

// Reads a colour image (.jpg/.jpeg via TurboJPEG, anything else via OpenCV) as RGB8, 3 channels.
// Greyscale files are expanded to RGB; 16-bit files are refused.
absl::StatusOr<ImageU8> ReadColorImage(const std::string& path);
// Writes RGB8 by extension: .jpg/.jpeg (TurboJPEG, `jpeg_quality`) or .png (OpenCV).
// 1-channel images are written as greyscale.
absl::Status WriteColorImage(const std::string& path, const ImageU8& rgb, int jpeg_quality = 90);

// 16-bit single-channel PNG (e.g. depth in mm). Refuses 8-bit or multi-channel files.
absl::StatusOr<ImageU16> ReadPng16(const std::string& path);
absl::Status WritePng16(const std::string& path, const ImageU16& image, int compression = 1);

}  // namespace exo
