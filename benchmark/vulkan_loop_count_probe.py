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
"""
import collections
import glob
import sys


def patch(tree):
    p = tree + '/shaders/blend_shade.glsl'
    s = open(p).read()
    a = '''  for (uint i = 0u; i < count; ++i) {
    const int t = kRankedTexels * int(offset + i);
    const uvec4 r0 = imageLoad(ranked_refs, t);
    if (uintBitsToFloat(r0.w) < nth) break;'''
    b = '''  return vec4(srgb, covered ? (in_roi ? 224.0 / 255.0 : 1.0) : 128.0 / 255.0);  // 224: inpainted'''
    assert a in s and b in s, 'blend_shade.glsl changed: update the probe'
    s = s.replace(a, a.replace('  for (uint i', '  uint iters = 0u;\n  for (uint i').replace(
        '    if (uintBitsToFloat', '    ++iters;\n    if (uintBitsToFloat'))
    s = s.replace(b, '  return vec4(float(iters) / 255.0, 1.0, float(count) / 255.0, 1.0);')
    open(p, 'w').write(s)


def count(dirs):
    import numpy as np
    from PIL import Image
    res = collections.OrderedDict()
    for d in dirs:
        for f in sorted(glob.glob(d + '/*_vulkan.png')):
            name = f.split('/')[-1]
            if '_f0_' in name:
                continue
            a = np.asarray(Image.open(f).convert('RGB')).astype(np.int64)
            m = a[..., 1] == 255
            it = np.where(m, a[..., 0], 0)
            h, w = it.shape
            blk = it[:h // 4 * 4, :w // 4 * 4].reshape(h // 4, 4, w // 4, 4).max(axis=(1, 3))
            bm = m[:h // 4 * 4, :w // 4 * 4].reshape(h // 4, 4, w // 4, 4).any(axis=(1, 3))
            s = res.setdefault((d, name.rsplit('_f', 1)[0]), [0, 0, 0, 0])
            s[0] += it[m].sum()
            s[1] += m.sum()
            s[2] += blk[bm].sum()
            s[3] += bm.sum()
    for (d, k), (it, n, bs, bn) in res.items():
        print(f'{d} {k}: surface px {n}, iterations/px {it / n:.3f}, '
              f'max per 4x4 block {bs / bn:.3f}')


if __name__ == '__main__':
    if len(sys.argv) == 3 and sys.argv[1] == 'patch':
        patch(sys.argv[2])
    elif len(sys.argv) >= 3 and sys.argv[1] == 'count':
        count(sys.argv[2:])
    else:
        sys.exit(__doc__)
