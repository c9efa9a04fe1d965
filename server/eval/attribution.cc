#include "server/eval/attribution.h"

#include <algorithm>
#include <cmath>

#include "common/lumigraph/blend_math.h"

namespace exo::eval {

TriangleMesh MeshFromDepth(const ImageF& depth_m, const PinholeCamera& camera,
                           const Rigid3d& local_from_cam, int step, float max_jump_rel) {
  TriangleMesh mesh;
  step = std::max(1, step);
  const int gw = (depth_m.width() - 1) / step + 1, gh = (depth_m.height() - 1) / step + 1;
  std::vector<int32_t> vid(size_t(gw) * gh, -1);
  std::vector<float> vz(size_t(gw) * gh, 0.0f);
  for (int j = 0; j < gh; ++j)
    for (int i = 0; i < gw; ++i) {
      const float z = depth_m.at(i * step, j * step);
      if (!blend::ValidDepth(z)) continue;
      const glm::dvec3 p = local_from_cam * camera.Unproject(glm::dvec2(i * step, j * step), z);
      vid[size_t(j) * gw + i] = int32_t(mesh.positions.size());
      vz[size_t(j) * gw + i] = z;
      mesh.positions.push_back(glm::vec3(p));
    }
  for (int j = 0; j + 1 < gh; ++j)
    for (int i = 0; i + 1 < gw; ++i) {
      const size_t k[4] = {size_t(j) * gw + i, size_t(j) * gw + i + 1, size_t(j + 1) * gw + i,
                           size_t(j + 1) * gw + i + 1};
      float lo = 1e30f, hi = 0.0f;
      bool ok = true;
      for (size_t q : k) {
        if (vid[q] < 0) ok = false;
        lo = std::min(lo, vz[q]);
        hi = std::max(hi, vz[q]);
      }
      if (!ok || hi - lo > max_jump_rel * lo) continue;
      for (uint32_t v : {vid[k[0]], vid[k[2]], vid[k[1]], vid[k[1]], vid[k[2]], vid[k[3]]})
        mesh.indices.push_back(v);
    }
  return mesh;
}

glm::vec3 FitGainToReference(ImageU8& render, const ImageU8& reference, const ImageU8& mask) {
  glm::dvec3 num(0.0), den(0.0);
  for (int y = 0; y < render.height(); ++y)
    for (int x = 0; x < render.width(); ++x) {
      if (mask.empty() || mask.at(x, y) == 0) continue;
      for (int c = 0; c < 3; ++c) {
        const double a = blend::SrgbToLinear(blend::U8ToUnit(render.at(x, y, c)));
        const double b = blend::SrgbToLinear(blend::U8ToUnit(reference.at(x, y, c)));
        num[c] += a * b;
        den[c] += a * a;
      }
    }
  glm::vec3 g(1.0f);
  for (int c = 0; c < 3; ++c)
    if (den[c] > 0) g[c] = float(num[c] / den[c]);
  if (g == glm::vec3(1.0f)) return g;
  for (int y = 0; y < render.height(); ++y)
    for (int x = 0; x < render.width(); ++x)
      for (int c = 0; c < 3; ++c)
        render.at(x, y, c) = blend::UnitToU8(blend::LinearToSrgb(
            g[c] * blend::SrgbToLinear(blend::U8ToUnit(render.at(x, y, c)))));
  return g;
}

}  // namespace exo::eval
