// Codec benchmark: JPEG q90 encode/decode (ms, bytes, ratio, PSNR) and the lossless depth codec
// candidates (ms, ratio, lossless check) on real 7-Scenes frames and synthetic images.
// One JSON object per line. Usage: codec_bench [--shared DIR] [--reps N] [--frames N]
#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <ctime>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "common/cli/cli.h"
#include "common/io/cv_adapter.h"
#include "common/io/depth_codec.h"
#include "common/io/image_file.h"
#include "common/io/jpeg.h"
#include "exoview_source_dir.h"

namespace exo {
namespace {

using Clock = std::chrono::steady_clock;
using json = nlohmann::ordered_json;  // fields in the order written

// Rounds to `digits` decimals for the JSON lines.
double Round(double x, int digits) {
  const double f = std::pow(10.0, digits);
  return std::round(x * f) / f;
}

double Ms(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}
// CPU time of this (single) thread in ms: beside the wall medians, steady on a loaded machine.
double ThreadCpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}
double Load1() {
  double l[1] = {0.0};
  return getloadavg(l, 1) == 1 ? l[0] : -1.0;
}
double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

double Psnr(const ImageU8& a, const ImageU8& b) {
  double se = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const double d = double(a.data()[i]) - b.data()[i];
    se += d * d;
  }
  return se == 0 ? 99.0 : 10 * std::log10(255.0 * 255.0 / (se / a.size()));
}

// Synthetic colour: procedural texture with edges and noise (photo-like statistics).
ImageU8 SyntheticRgb(int w, int h) {
  std::mt19937 rng(42);
  ImageU8 img(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const bool brick = ((x / 24 + (y / 12) % 2) % 2) == 0 && (y % 12) != 0;
      const double base = brick ? 170 : 90;
      for (int c = 0; c < 3; ++c) {
        const double v = base + 40 * std::sin(0.07 * x + c) * std::cos(0.05 * y) +
                         static_cast<int>(rng() % 17) - 8;
        img.at(x, y, c) = static_cast<uint8_t>(std::clamp(v, 0.0, 255.0));
      }
    }
  return img;
}

// Synthetic depth in mm: two slanted planes, boxes, a sphere, holes, 1 mm sensor noise.
ImageU16 SyntheticDepth(int w, int h) {
  std::mt19937 rng(7);
  ImageU16 d(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double z = y > h / 2 ? 1200 + 6.0 * (h - y) : 3500 - 0.8 * x;
      const double dx = x - w * 0.6, dy = y - h * 0.4, r = h * 0.18;
      if (dx * dx + dy * dy < r * r) z = 1600 - std::sqrt(r * r - dx * dx - dy * dy) * 2.0;
      if (x > w / 8 && x < w / 4 && y > h / 3 && y < h * 3 / 4) z = 900;
      z += static_cast<int>(rng() % 3) - 1;
      if (x < 8 || (rng() % 100) < 3) z = 0;
      d.at(x, y) = static_cast<uint16_t>(z);
    }
  return d;
}

void BenchJpeg(const std::string& source, const ImageU8& img, int reps) {
  std::vector<double> enc, dec;
  std::vector<uint8_t> bytes;
  ImageU8 back;
  for (int r = 0; r < reps; ++r) {
    auto t0 = Clock::now();
    bytes = *EncodeJpeg(img, 90);
    auto t1 = Clock::now();
    back = *DecodeJpeg(bytes);
    auto t2 = Clock::now();
    enc.push_back(Ms(t0, t1));
    dec.push_back(Ms(t1, t2));
  }
  const json line = {{"bench", "jpeg"},
                     {"source", source},
                     {"width", img.width()},
                     {"height", img.height()},
                     {"quality", 90},
                     {"encode_ms", Round(Median(enc), 3)},
                     {"decode_ms", Round(Median(dec), 3)},
                     {"bytes", bytes.size()},
                     {"ratio", Round(double(img.bytes()) / bytes.size(), 2)},
                     {"psnr_db", Round(Psnr(img, back), 2)}};
  std::printf("%s\n", line.dump().c_str());
}

void BenchDepth(const std::string& source, const std::vector<ImageU16>& frames, int reps) {
  struct Cand {
    DepthCodec codec;
    int level;
  };
  const Cand cands[] = {{DepthCodec::kPng, 1},          {DepthCodec::kPng, 3},
                        {DepthCodec::kRawZstd, 1},      {DepthCodec::kRawZstd, 3},
                        {DepthCodec::kDeltaZstd, 1},    {DepthCodec::kDeltaZstd, 3},
                        {DepthCodec::kDeltaPlanesZstd, 1}, {DepthCodec::kDeltaPlanesZstd, 3},
                        {DepthCodec::kDeltaPlanesZstd, 6}};
  for (const Cand& c : cands) {
    DepthCodecOptions o;
    o.codec = c.codec;
    if (c.codec == DepthCodec::kPng) o.png_compression = c.level;
    else o.zstd_level = c.level;
    std::vector<double> enc, dec, enc_cpu, dec_cpu;
    size_t raw = 0, packed = 0;
    bool lossless = true;
    for (const ImageU16& d : frames) {
      std::vector<uint8_t> bytes;
      for (int r = 0; r < reps; ++r) {
        const double c0 = ThreadCpuMs();
        auto t0 = Clock::now();
        bytes = *EncodeDepth(d, o);
        auto t1 = Clock::now();
        const double c1 = ThreadCpuMs();
        auto back = DecodeDepth(bytes);
        auto t2 = Clock::now();
        const double c2 = ThreadCpuMs();
        enc.push_back(Ms(t0, t1));
        dec.push_back(Ms(t1, t2));
        enc_cpu.push_back(c1 - c0);
        dec_cpu.push_back(c2 - c1);
        lossless = lossless && back.ok() && *back == d;
      }
      raw += d.bytes();
      packed += bytes.size();
    }
    const json line = {{"bench", "depth"},
                       {"source", source},
                       {"frames", frames.size()},
                       {"width", frames[0].width()},
                       {"height", frames[0].height()},
                       {"codec", std::string(DepthCodecName(c.codec))},
                       {"level", c.level},
                       {"encode_ms", Round(Median(enc), 3)},
                       {"decode_ms", Round(Median(dec), 3)},
                       {"encode_cpu_ms", Round(Median(enc_cpu), 3)},
                       {"decode_cpu_ms", Round(Median(dec_cpu), 3)},
                       {"bytes_per_frame", packed / frames.size()},
                       {"ratio", Round(double(raw) / packed, 3)},
                       {"lossless", lossless},
                       {"load1", Round(Load1(), 2)}};
    std::printf("%s\n", line.dump().c_str());
  }
}

int Main(int argc, char** argv) {
  std::string shared = std::getenv("EXOVIEW_SHARED_DIR") ? std::getenv("EXOVIEW_SHARED_DIR")
                                                         : std::string(EXOVIEW_SOURCE_DIR) + "/../shared";
  int reps = 10, frames = 30;
  CLI::App app{"Codec benchmark: JPEG q90 and the lossless depth codecs on 7-Scenes and synthetic "
               "images; one JSON object per line on stdout.",
               "codec_bench"};
  exo::cli::Setup(app);
  app.add_option("--shared", shared, "the shared folder (data/7scenes-redkitchen inside)");
  app.add_option("--reps", reps, "repetitions per image")
      ->check(CLI::PositiveNumber);
  app.add_option("--frames", frames, "7-Scenes depth frames for the depth codecs")
      ->check(CLI::PositiveNumber);
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  const std::string dir = shared + "/data/7scenes-redkitchen";
  const bool have_real = std::filesystem::exists(dir + "/frame-000000.color.jpg");
  if (have_real) {
    auto rgb = ReadColorImage(dir + "/frame-000000.color.jpg");
    if (rgb.ok()) {
      BenchJpeg("7scenes", *rgb, reps);
      ImageU8 big(1280, 720, 3);
      cv::resize(CvView(*rgb), CvView(big), cv::Size(1280, 720), 0, 0, cv::INTER_CUBIC);
      BenchJpeg("7scenes_upscaled", big, reps);
    }
  } else {
    std::fprintf(stderr, "7-Scenes data not found under %s: synthetic only\n", dir.c_str());
  }
  BenchJpeg("synthetic", SyntheticRgb(640, 480), reps);
  BenchJpeg("synthetic", SyntheticRgb(1280, 720), reps);

  if (have_real) {
    std::vector<ImageU16> depth;
    for (int i = 0; i < frames; ++i) {
      char name[64];
      std::snprintf(name, sizeof(name), "/frame-%06d.depth.png", i * 300 / frames);
      auto d = ReadPng16(dir + name);
      if (d.ok()) depth.push_back(*std::move(d));
    }
    if (!depth.empty()) BenchDepth("7scenes", depth, std::max(1, reps / 2));
  }
  BenchDepth("synthetic", {SyntheticDepth(640, 480)}, reps);
  return 0;
}

}  // namespace
}  // namespace exo

int main(int argc, char** argv) { return exo::Main(argc, argv); }
