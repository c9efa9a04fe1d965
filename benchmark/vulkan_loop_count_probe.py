#!/usr/bin/python3
"""Reference-loop iteration counts of the Vulkan blend (issue 16, docs/vulkan.md session 17).

A shader probe, load-independent: `patch TREE` rewrites TREE/shaders/blend_shade.glsl (a copy of
the sources, never the working tree) so that the surface pass writes, per pixel, the number of
ranked-reference loop iterations (the stopping one included) into R, 255 into G and the cell's
reference count into B. Build vulkan_bench in that tree, dump frames with
  EXO_VULKAN_BENCH_DUMP=DIR vulkan_bench --frames=8 --refs=16 --sizes=1280x720 \
      --fill_holes=0 --background_views=0
and `count DIR...` prints, per dump directory and configuration (frames f1.., the timed ones),
the mean iterations per surface pixel and the mean over 4x4 pixel blocks of the block's maximum
(llvmpipe shades a 4x4 block as two 8-lane vectors and runs a loop while any lane is active).

Three loop forms are recognised, each counting the loop bodies a pixel's lane runs: before
session 18 the stop was tested at the top of the body (the stopping iteration is counted: llvmpipe
runs it as a masked body); the session-18 loop with the stop at the end of the body; the
session-18 scan form (R = outer bodies, i.e. validity evaluations, B = inner scan iterations,
i.e. weight evaluations; `count` prints B's mean as B/px). `patch-reasons TREE MODE` (session 18; the loop form before session 18
only) writes the iterations into R, 255 into G and into B two
counts of how iterations ended, each capped at 15, as B = first + 16 * second: MODE `frustum` =
(behind the view or outside its image, stored depth <= 0), MODE `skip` = (occluded, weight below
the n-th best before the validity test). `reasons DIR...` prints their means per surface pixel
(the stopping iteration and the valid ones are the rest).
"""
import collections
import glob
import sys


def patch(tree):
    p = tree + '/shaders/blend_shade.glsl'
    s = open(p).read()
    # Before session 18: the stop tested at the top of the body (the stopping iteration counts).
    a = '''  for (uint i = 0u; i < count; ++i) {
    const int t = kRankedTexels * int(offset + i);
    const uvec4 r0 = imageLoad(ranked_refs, t);
    if (uintBitsToFloat(r0.w) < nth) break;'''
    # Since session 18: the stop tested at the end of the body (every iteration is a body).
    a18 = '''  uvec4 r0 = uvec4(0u);
  if (count > 0u) r0 = imageLoad(ranked_refs, kRankedTexels * int(offset));'''
    a18_body = '''    for (uint i = 0u;;) {''' + ('''
      const int t = kRankedTexels * int(offset + i);''' if 'const int t = kRankedTexels * int(offset + i);\n      // ---- weights' in s else '')
    b = '''  return vec4(srgb, covered ? (in_roi ? 224.0 / 255.0 : 1.0) : 128.0 / 255.0);  // 224: inpainted'''
    assert b in s, 'blend_shade.glsl changed: update the probe'
    scan = '''      for (;;) {
        b = uintBitsToFloat(r0.xyz) - x;'''
    if a in s:
        s = s.replace(a, a.replace('  for (uint i', '  uint iters = 0u;\n  for (uint i').replace(
            '    if (uintBitsToFloat', '    ++iters;\n    if (uintBitsToFloat'))
    elif scan in s:
        # Since session 18 (scan form): R = outer bodies (validity evaluations), B = inner scan
        # iterations (weights), each per pixel.
        assert s.count(a18) == 1 and s.count(a18_body) == 1 and s.count(scan) == 1, 'update the probe'
        s = s.replace(a18, '  uint iters = 0u, scans = 0u;\n' + a18)
        s = s.replace(a18_body, a18_body + '\n      ++iters;')
        s = s.replace(scan, scan.replace('      for (;;) {', '      for (;;) {\n        ++scans;'))
        s = s.replace(b, '  return vec4(float(iters) / 255.0, 1.0, float(scans) / 255.0, 1.0);')
    else:
        assert s.count(a18) == 1 and s.count(a18_body) == 1, 'blend_shade.glsl changed: update the probe'
        s = s.replace(a18, '  uint iters = 0u;\n' + a18)
        s = s.replace(a18_body, a18_body + '\n      ++iters;')
    s = s.replace(b, '  return vec4(float(iters) / 255.0, 1.0, float(count) / 255.0, 1.0);')
    open(p, 'w').write(s)


def patch_reasons(tree, mode):
    p = tree + '/shaders/blend_shade.glsl'
    s = open(p).read()
    reps = [
        ('  for (uint i = 0u; i < count; ++i) {\n    const int t',
         '  uint iters = 0u, r_fr = 0u, r_d0 = 0u, r_occ = 0u, r_w = 0u;\n'
         '  for (uint i = 0u; i < count; ++i) {\n    ++iters;\n    const int t'),
        ('    if (!(w >= nth)) continue;', '    if (!(w >= nth)) { ++r_w; continue; }'),
        ('    if (!(z > kMinDistance)) continue;\n    const vec2 uv = vec2(dot(uintBitsToFloat(m0',
         '    if (!(z > kMinDistance)) { ++r_fr; continue; }\n'
         '    const vec2 uv = vec2(dot(uintBitsToFloat(m0'),
        ('    if (!(uv.x >= -0.5 && uv.y >= -0.5 && uv.x < size.x - 0.5 && uv.y < size.y - 0.5)) '
         'continue;\n    const vec2 pc = clamp(floor(uv + 0.5), vec2(0.0), size - 1.0);\n'
         '    const float z_stored = imageLoad(depths, ivec3(ivec2(pc), layer)).r;',
         '    if (!(uv.x >= -0.5 && uv.y >= -0.5 && uv.x < size.x - 0.5 && uv.y < size.y - 0.5)) '
         '{ ++r_fr; continue; }\n    const vec2 pc = clamp(floor(uv + 0.5), vec2(0.0), size - 1.0);\n'
         '    const float z_stored = imageLoad(depths, ivec3(ivec2(pc), layer)).r;'),
        ('    if (!(z_stored > 0.0)) continue;', '    if (!(z_stored > 0.0)) { ++r_d0; continue; }'),
        ('    if (range_m > range_d + eps_abs + eps_rel * range_d) continue;',
         '    if (range_m > range_d + eps_abs + eps_rel * range_d) { ++r_occ; continue; }'),
    ]
    for a, b in reps:
        assert s.count(a) == 1, 'blend_shade.glsl changed: update the probe: ' + a[:40]
        s = s.replace(a, b)
    end = ('  return vec4(srgb, covered ? (in_roi ? 224.0 / 255.0 : 1.0) : 128.0 / 255.0);'
           '  // 224: inpainted')
    assert s.count(end) == 1, 'blend_shade.glsl changed: update the probe'
    first, second = ('r_fr', 'r_d0') if mode == 'frustum' else ('r_occ', 'r_w')
    s = s.replace(end, f'  return vec4(float(iters) / 255.0, 1.0, float(min({first}, 15u) + '
                       f'16u * min({second}, 15u)) / 255.0, 1.0);')
    open(p, 'w').write(s)


def timed_frames(dirs):
    """(dir, configuration, RGB int64 array) of every timed frame (f1..) in the dump dirs."""
    import numpy as np
    from PIL import Image
    for d in dirs:
        for f in sorted(glob.glob(d + '/*_vulkan.png')):
            name = f.split('/')[-1]
            if '_f0_' in name:
                continue
            yield d, name.rsplit('_f', 1)[0], np.asarray(Image.open(f).convert('RGB')).astype(np.int64)


def reasons(dirs):
    res = collections.OrderedDict()
    for d, config, a in timed_frames(dirs):
        m = a[..., 1] == 255
        s = res.setdefault((d, config), [0, 0, 0, 0])
        s[0] += a[..., 0][m].sum()
        s[1] += (a[..., 2][m] % 16).sum()
        s[2] += (a[..., 2][m] // 16).sum()
        s[3] += m.sum()
    for (d, k), (it, r1, r2, n) in res.items():
        print(f'{d} {k}: surface px {n}, iterations/px {it / n:.3f}, '
              f'first reason/px {r1 / n:.3f}, second reason/px {r2 / n:.3f}')


def count(dirs):
    import numpy as np
    res = collections.OrderedDict()
    for d, config, a in timed_frames(dirs):
        m = a[..., 1] == 255
        it = np.where(m, a[..., 0], 0)
        h, w = it.shape
        blk = it[:h // 4 * 4, :w // 4 * 4].reshape(h // 4, 4, w // 4, 4).max(axis=(1, 3))
        bm = m[:h // 4 * 4, :w // 4 * 4].reshape(h // 4, 4, w // 4, 4).any(axis=(1, 3))
        s = res.setdefault((d, config), [0, 0, 0, 0, 0])
        s[4] += a[..., 2][m].sum()
        s[0] += it[m].sum()
        s[1] += m.sum()
        s[2] += blk[bm].sum()
        s[3] += bm.sum()
    for (d, k), (it, n, bs, bn, bsum) in res.items():
        print(f'{d} {k}: surface px {n}, iterations/px {it / n:.3f}, '
              f'max per 4x4 block {bs / bn:.3f}, B/px {bsum / n:.3f}')


if __name__ == '__main__':
    if len(sys.argv) == 3 and sys.argv[1] == 'patch':
        patch(sys.argv[2])
    elif len(sys.argv) == 4 and sys.argv[1] == 'patch-reasons':
        patch_reasons(sys.argv[2], sys.argv[3])
    elif len(sys.argv) >= 3 and sys.argv[1] == 'count':
        count(sys.argv[2:])
    elif len(sys.argv) >= 3 and sys.argv[1] == 'reasons':
        reasons(sys.argv[2:])
    else:
        sys.exit(__doc__)
