#include "common/lumigraph/vertex_color.h"

#include "common/lumigraph/blend_math.h"
#include "common/raster/rasterizer.h"

namespace exo {

absl::Status RenderVertexColor(const TriangleMesh& mesh, const PinholeCamera& cam,
                               const Rigid3d& local_from_cam, ImageU8* img, ImageU8* mask) {
  const int w = cam.width, h = cam.height;
  *img = ImageU8(w, h, 3, 0);
  *mask = ImageU8(w, h, 1, 0);
  if (mesh.empty() || mesh.colors.size() != mesh.positions.size()) return absl::OkStatus();
  RasterOptions ro;
  ro.z_depth = false;
  ro.position = true;
  ro.triangle_id = true;
  EXO_ASSIGN_OR_RETURN(RasterOutput r, Rasterize(mesh, cam, local_from_cam, ro));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const uint32_t tri = r.triangle_id.at(x, y);
      if (tri == kNoTriangle) continue;
      const glm::vec3 p(r.position_local.at(x, y, 0), r.position_local.at(x, y, 1),
                        r.position_local.at(x, y, 2));
      const uint32_t* ix = &mesh.indices[3 * size_t(tri)];
      const glm::vec3 a = mesh.positions[ix[0]], b = mesh.positions[ix[1]],
                      c = mesh.positions[ix[2]];
      // Barycentric weights of p in the triangle (areas of the sub-triangles).
      const glm::vec3 nrm = glm::cross(b - a, c - a);
      const float nn = glm::dot(nrm, nrm);
      glm::vec3 col;
      if (nn > 0) {
        const float wa = glm::dot(glm::cross(c - b, p - b), nrm) / nn;
        const float wb = glm::dot(glm::cross(a - c, p - c), nrm) / nn;
        const float wc = 1.0f - wa - wb;
        col = wa * mesh.colors[ix[0]] + wb * mesh.colors[ix[1]] + wc * mesh.colors[ix[2]];
      } else {
        col = mesh.colors[ix[0]];
      }
      for (int ch = 0; ch < 3; ++ch)
        img->at(x, y, ch) = blend::UnitToU8(blend::LinearToSrgb(col[ch]));
      mask->at(x, y) = 255;
    }
  return absl::OkStatus();
}

}  // namespace exo
