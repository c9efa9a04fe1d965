// eval_charts: draws the charts of docs/evaluation.md from exoview_eval's JSON lines (OpenCV).
//   eval_charts results.jsonl OUT_DIR
// Writes OUT_DIR/eval_store.png (MSSIM vs store size), eval_sweeps.png (MSSIM vs R_max, lambda,
// cell size, delta_tau_sum), eval_voxel.png (MSSIM vs integrate CPU ms over the voxel-size sweep,
// points labelled with the voxel size), eval_speed_error.png (per-frame ms vs 1 - MSSIM, every config).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace {

// Value of "key": in a flat JSON line (keys of exoview_eval lines are unique per line).
std::string Field(const std::string& line, const std::string& key) {
  const std::string k = "\"" + key + "\":";
  const size_t p = line.find(k);
  if (p == std::string::npos) return "";
  size_t b = p + k.size();
  if (line[b] == '"') {
    const size_t e = line.find('"', b + 1);
    return line.substr(b + 1, e - b - 1);
  }
  size_t e = b;
  while (e < line.size() && line[e] != ',' && line[e] != '}') ++e;
  return line.substr(b, e - b);
}
double Num(const std::string& line, const std::string& key) {
  const std::string v = Field(line, key);
  return v.empty() ? 0.0 : std::stod(v);
}

struct Series {
  std::string name;
  cv::Scalar color;
  std::vector<cv::Point2d> pts;
  bool line = true;
  std::vector<std::string> labels;  // optional text beside each point (same order as pts)
  bool hollow = false;              // open circles (contrast points)
};

// One chart panel: axes, ticks, series, legend.
void Panel(cv::Mat& img, cv::Rect r, const std::string& title, const std::string& xlab,
           const std::string& ylab, std::vector<Series> series, bool logx = false,
           bool legend_bottom = false) {
  cv::rectangle(img, r, cv::Scalar(255, 255, 255), cv::FILLED);
  double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
  auto tx = [&](double x) { return logx ? std::log2(std::max(x, 1e-9)) : x; };
  for (auto& s : series)
    for (auto& p : s.pts) {
      x0 = std::min(x0, tx(p.x));
      x1 = std::max(x1, tx(p.x));
      y0 = std::min(y0, p.y);
      y1 = std::max(y1, p.y);
    }
  if (x0 > x1) return;
  if (x1 - x0 < 1e-9) { x0 -= 1; x1 += 1; }
  const double padx = 0.07 * (x1 - x0);  // room for the points' labels at both ends
  x0 -= padx;
  x1 += padx;
  if (y1 - y0 < 1e-3) { y0 -= 0.01; y1 += 0.01; }
  const double py = 0.08 * (y1 - y0);
  y0 -= py;
  y1 += py;
  const int L = r.x + 60, R = r.x + r.width - 15, T = r.y + 48, B = r.y + r.height - 45;
  auto px = [&](double x) { return L + (tx(x) - x0) / (x1 - x0) * (R - L); };
  auto py_ = [&](double y) { return B - (y - y0) / (y1 - y0) * (B - T); };
  cv::rectangle(img, cv::Point(L, T), cv::Point(R, B), cv::Scalar(0, 0, 0), 1);
  for (int i = 0; i <= 4; ++i) {
    const double y = y0 + (y1 - y0) * i / 4;
    const int yy = int(py_(y));
    cv::line(img, cv::Point(L, yy), cv::Point(R, yy), cv::Scalar(225, 225, 225), 1);
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.3f", y);
    cv::putText(img, buf, cv::Point(r.x + 4, yy + 4), cv::FONT_HERSHEY_SIMPLEX, 0.38, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
    const double xv = x0 + (x1 - x0) * i / 4;
    const double xt = logx ? std::exp2(xv) : xv;
    std::snprintf(buf, sizeof buf, std::abs(xt) >= 10 ? "%.0f" : "%.4g", xt);
    cv::putText(img, buf, cv::Point(int(L + (R - L) * i / 4.0) - 12, B + 16), cv::FONT_HERSHEY_SIMPLEX, 0.38, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  }
  cv::putText(img, title, cv::Point(L, r.y + 20), cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  cv::putText(img, xlab, cv::Point((L + R) / 2 - 60, B + 36), cv::FONT_HERSHEY_SIMPLEX, 0.42, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  cv::putText(img, ylab, cv::Point(r.x + 4, T - 8), cv::FONT_HERSHEY_SIMPLEX, 0.42, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  int ly = legend_bottom ? B - 8 - 16 * (int(series.size()) - 1) : T + 14;
  for (auto& s : series) {
    std::vector<size_t> ord(s.pts.size());
    for (size_t i = 0; i < ord.size(); ++i) ord[i] = i;
    std::sort(ord.begin(), ord.end(), [&](size_t a, size_t b) { return s.pts[a].x < s.pts[b].x; });
    std::vector<cv::Point2d> sorted;
    std::vector<std::string> labels;
    for (size_t i : ord) {
      sorted.push_back(s.pts[i]);
      if (i < s.labels.size()) labels.push_back(s.labels[i]);
    }
    s.pts = sorted;
    for (size_t i = 0; i < s.pts.size(); ++i) {
      const cv::Point p(int(px(s.pts[i].x)), int(py_(s.pts[i].y)));
      cv::circle(img, p, s.hollow ? 6 : 4, s.color, s.hollow ? 2 : cv::FILLED, cv::LINE_AA);
      if (i < labels.size())
        cv::putText(img, labels[i], p + cv::Point(6, s.hollow ? 14 : -6), cv::FONT_HERSHEY_SIMPLEX,
                    0.36, s.color, 1, cv::LINE_AA);
      if (s.line && i > 0)
        cv::line(img, cv::Point(int(px(s.pts[i - 1].x)), int(py_(s.pts[i - 1].y))), p, s.color, 2, cv::LINE_AA);
    }
    cv::circle(img, cv::Point(R - 190, ly - 4), 4, s.color, s.hollow ? 1 : cv::FILLED, cv::LINE_AA);
    cv::putText(img, s.name, cv::Point(R - 180, ly), cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
    ly += 16;
  }
}

const cv::Scalar kColors[] = {{200, 80, 30}, {40, 40, 220}, {40, 160, 40}, {160, 40, 160},
                              {0, 150, 220}, {120, 120, 120}, {0, 0, 0}};

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: eval_charts results.jsonl OUT_DIR\n");
    return 2;
  }
  std::ifstream in(argv[1]);
  const std::string out = argv[2];
  std::vector<std::string> lines;
  for (std::string l; std::getline(in, l);)
    if (Field(l, "bench") == "eval") lines.push_back(l);
  const std::vector<std::string> scenes = {"village/flyover", "apartment/walk"};

  // Quality vs store size.
  {
    cv::Mat img(360, 560, CV_8UC3, cv::Scalar(255, 255, 255));
    std::vector<Series> ss;
    int c = 0;
    for (const auto& sc : scenes) {
      Series s{sc, kColors[c++]};
      for (const auto& l : lines)
        if (Field(l, "dataset") == sc && Field(l, "tag") == "sweep_store")
          s.pts.push_back({Num(l, "store"), Num(l, "mssim")});
      if (!s.pts.empty()) ss.push_back(s);
    }
    Panel(img, cv::Rect(0, 0, 560, 360), "MSSIM vs view store size (online planner, TSDF proxy)",
          "store size (views, log2)", "MSSIM", ss, true);
    cv::imwrite(out + "/eval_store.png", img);
  }
  // Other sweeps.
  {
    cv::Mat img(720, 1120, CV_8UC3, cv::Scalar(255, 255, 255));
    const std::vector<std::pair<std::string, std::string>> sw = {
        {"sweep_r_max", "r_max"}, {"sweep_lambda", "lambda"}, {"sweep_cell", "cell_m"},
        {"sweep_dts", "delta_tau_sum"}};
    for (size_t i = 0; i < sw.size(); ++i) {
      std::vector<Series> ss;
      int c = 0;
      for (const auto& sc : scenes) {
        Series s{sc, kColors[c++]};
        for (const auto& l : lines)
          if (Field(l, "dataset") == sc && Field(l, "tag") == sw[i].first)
            s.pts.push_back({Num(l, sw[i].second), Num(l, "mssim")});
        if (!s.pts.empty()) ss.push_back(s);
      }
      Panel(img, cv::Rect(560 * (i % 2), 360 * (i / 2), 560, 360), "MSSIM vs " + sw[i].second,
            sw[i].second, "MSSIM", ss, sw[i].second == "r_max");
    }
    cv::imwrite(out + "/eval_sweeps.png", img);
  }
  // Voxel size as a speed-vs-error knob (session 4): MSSIM vs integrate CPU ms per input frame,
  // one line per scene (runs tagged voxel_fixedlod: cell-id LOD held fixed), points labelled
  // with the voxel size; runs tagged voxel_defaultlod (voxel-dependent LOD) as open circles.
  // Left: near-trajectory test poses, right: scene-wide.
  {
    cv::Mat img(400, 1120, CV_8UC3, cv::Scalar(255, 255, 255));
    const std::vector<std::string> sets = {"near", "scene"};
    for (size_t k = 0; k < sets.size(); ++k) {
      std::vector<Series> ss;
      int c = 0;
      for (const auto& sc : scenes) {
        const cv::Scalar col = kColors[c++];
        const std::string name = sc.substr(0, sc.find('/'));
        for (const char* tag : {"voxel_fixedlod", "voxel_defaultlod"}) {
          const bool fixed = std::string(tag) == "voxel_fixedlod";
          Series s{name + (fixed ? ", fixed LOD" : ", default LOD"), col, {}, fixed, {}, !fixed};
          for (const auto& l : lines) {
            if (Field(l, "dataset") != sc || Field(l, "tag") != tag || Field(l, "test_poses") != sets[k])
              continue;
            s.pts.push_back({Num(l, "integrate_cpu_ms_median"), Num(l, "mssim")});
            char buf[32];
            std::snprintf(buf, sizeof buf, "%.3g cm", 100.0 * Num(l, "voxel_m"));
            s.labels.push_back(buf);
          }
          if (!s.pts.empty()) ss.push_back(s);
        }
        // The same protocol with the ground-truth mesh as proxy (runs tagged gt_ref): a
        // horizontal line over the scene's TSDF points, the ceiling a finer voxel approaches.
        double xmin = 1e300, xmax = -1e300;
        for (const auto& l : lines)
          if (Field(l, "dataset") == sc && Field(l, "tag") == "voxel_fixedlod") {
            xmin = std::min(xmin, Num(l, "integrate_cpu_ms_median"));
            xmax = std::max(xmax, Num(l, "integrate_cpu_ms_median"));
          }
        for (const auto& l : lines)
          if (xmin <= xmax && Field(l, "dataset") == sc && Field(l, "tag") == "gt_ref" &&
              Field(l, "test_poses") == sets[k]) {
            const cv::Scalar light = 0.45 * col + 0.55 * cv::Scalar(255, 255, 255);
            Series g{name + ", GT mesh proxy", light, {{xmin, Num(l, "mssim")}, {xmax, Num(l, "mssim")}}};
            ss.push_back(g);
          }
      }
      Panel(img, cv::Rect(560 * k, 0, 560, 400),
            "MSSIM (" + sets[k] + " test poses) vs TSDF voxel size",
            "integrate CPU ms per frame (median, log)", "MSSIM", ss, true,
            /*legend_bottom=*/sets[k] == "near");  // where each panel has room
    }
    cv::imwrite(out + "/eval_voxel.png", img);
  }
  // Speed vs error: integrate + plan median ms per input frame vs 1 - MSSIM, per policy.
  {
    cv::Mat img(360, 1120, CV_8UC3, cv::Scalar(255, 255, 255));
    for (size_t k = 0; k < scenes.size(); ++k) {
      std::map<std::string, Series> by;
      int c = 0;
      for (const auto& l : lines) {
        if (Field(l, "dataset") != scenes[k] || Field(l, "proxy") != "tsdf") continue;
        std::string name = Field(l, "policy");
        const std::string tag = Field(l, "tag");
        if (tag == "sweep_store" || tag == "sweep_r_max") name = "online, " + tag.substr(6) + " sweep";
        else if (tag.rfind("sweep", 0) == 0) continue;
        auto it = by.find(name);
        if (it == by.end()) it = by.emplace(name, Series{name, kColors[c++ % 7], {}, false}).first;
        it->second.pts.push_back({Num(l, "integrate_ms_median") + Num(l, "plan_ms_median"),
                                  1.0 - Num(l, "mssim")});
      }
      std::vector<Series> ss;
      for (auto& [n, s] : by) ss.push_back(s);
      Panel(img, cv::Rect(560 * k, 0, 560, 360), "speed vs error: " + scenes[k],
            "integrate + plan, median ms per input frame", "1 - MSSIM", ss);
    }
    cv::imwrite(out + "/eval_speed_error.png", img);
  }
  return 0;
}
