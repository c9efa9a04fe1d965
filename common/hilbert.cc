#include "common/hilbert.h"

#include <algorithm>
#include <cstddef>
#include <utility>

namespace exo {

std::vector<glm::dvec2> HilbertCurve(int order) {
  const int n = 1 << std::max(0, order);
  std::vector<glm::dvec2> pts;
  pts.reserve(static_cast<size_t>(n) * n);
  for (int d = 0; d < n * n; ++d) {  // index -> cell (x, y) of the curve
    int x = 0, y = 0, t = d;
    for (int s = 1; s < n; s *= 2) {
      const int rx = 1 & (t / 2), ry = 1 & (t ^ rx);
      if (ry == 0) {
        if (rx == 1) {
          x = s - 1 - x;
          y = s - 1 - y;
        }
        std::swap(x, y);
      }
      x += s * rx;
      y += s * ry;
      t /= 4;
    }
    pts.push_back({n > 1 ? double(x) / (n - 1) : 0.5, n > 1 ? double(y) / (n - 1) : 0.5});
  }
  return pts;
}

}  // namespace exo
