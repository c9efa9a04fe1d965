// Test-only builders of the hostile inputs of issue 20 (not part of the library): a progressive
// JPEG with hundreds of legal scans (a CPU bomb), depth streams whose header or payload claims
// another size or another image format (PGM, a PNG header claiming 16384 x 16384). Used by the
// io tests, the service attack tests and the fuzz seed corpus. Needs libjpeg (JPEG::JPEG).
#pragma once

#include <jpeglib.h>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

namespace exo::hostile {

// A `w` x `h` greyscale progressive JPEG with 1 + 10 * 63 + 9 = 640 scans: DC and every AC
// coefficient sent one bit plane at a time (a legal progression; libjpeg validates it).
inline std::vector<uint8_t> ManyScanProgressiveJpeg(int w, int h) {
  std::vector<jpeg_scan_info> scans;
  scans.push_back({1, {0, 0, 0, 0}, 0, 0, 0, 9});  // DC first, Al = 9
  for (int al = 8; al >= 0; --al) scans.push_back({1, {0, 0, 0, 0}, 0, 0, al + 1, al});
  for (int k = 1; k < 64; ++k) {
    scans.push_back({1, {0, 0, 0, 0}, k, k, 0, 9});
    for (int al = 8; al >= 0; --al) scans.push_back({1, {0, 0, 0, 0}, k, k, al + 1, al});
  }
  jpeg_compress_struct c;
  jpeg_error_mgr err;
  c.err = jpeg_std_error(&err);
  jpeg_create_compress(&c);
  unsigned char* out = nullptr;
  unsigned long out_size = 0;  // NOLINT(runtime/int): libjpeg's type
  jpeg_mem_dest(&c, &out, &out_size);
  c.image_width = static_cast<JDIMENSION>(w);
  c.image_height = static_cast<JDIMENSION>(h);
  c.input_components = 1;
  c.in_color_space = JCS_GRAYSCALE;
  jpeg_set_defaults(&c);
  jpeg_set_quality(&c, 95, TRUE);
  c.scan_info = scans.data();
  c.num_scans = static_cast<int>(scans.size());
  jpeg_start_compress(&c, TRUE);
  std::vector<uint8_t> row(static_cast<size_t>(w));
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) row[x] = static_cast<uint8_t>((x * 37 + y * 91 + x * y) % 251);
    JSAMPROW r = row.data();
    jpeg_write_scanlines(&c, &r, 1);
  }
  jpeg_finish_compress(&c);
  jpeg_destroy_compress(&c);
  std::vector<uint8_t> bytes(out, out + out_size);
  free(out);
  return bytes;
}

// Number of SOS markers (scans) in a JPEG stream (entropy-coded data never holds FF DA).
inline int CountJpegScans(const std::vector<uint8_t>& j) {
  int n = 0;
  for (size_t i = 0; i + 1 < j.size(); ++i)
    if (j[i] == 0xFF && j[i + 1] == 0xDA) ++n;
  return n;
}

// An EXD1 depth stream (common/io/depth_codec.h layout) around any payload.
inline std::string DepthStream(uint8_t codec, uint32_t w, uint32_t h, const std::string& payload) {
  std::string s(24, '\0');
  std::memcpy(s.data(), "EXD1", 4);
  s[4] = 1;
  s[5] = static_cast<char>(codec);
  auto put = [&](size_t at, uint32_t v) {
    for (int i = 0; i < 4; ++i) s[at + i] = static_cast<char>(v >> (8 * i));
  };
  put(8, w);
  put(12, h);
  put(16, static_cast<uint32_t>(payload.size()));
  return s + payload;
}

// A 16-bit binary PGM (another format OpenCV's imdecode would have decoded).
inline std::string Pgm16(int w, int h) {
  std::string s = "P5\n" + std::to_string(w) + " " + std::to_string(h) + "\n65535\n";
  s.append(static_cast<size_t>(w) * h * 2, '\x01');
  return s;
}

// A PNG signature + IHDR chunk claiming `w` x `h` (CRC not filled: nothing may get that far).
inline std::string PngHeader(uint32_t w, uint32_t h, int bit_depth = 16, int colour_type = 0) {
  std::string s = "\x89PNG\r\n\x1a\n";
  auto be = [&](uint32_t v) {
    for (int i = 3; i >= 0; --i) s.push_back(static_cast<char>(v >> (8 * i)));
  };
  be(13);
  s += "IHDR";
  be(w);
  be(h);
  s.push_back(static_cast<char>(bit_depth));
  s.push_back(static_cast<char>(colour_type));
  s.append(3, '\0');  // compression, filter, interlace
  be(0);              // CRC
  s.append(64, '\0');
  return s;
}

}  // namespace exo::hostile
