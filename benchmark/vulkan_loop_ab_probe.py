#!/usr/bin/python3
"""In-process A/B timing of two forms of the blend's reference loop (issue 16, session 18).

Under load (2 cores shared by several agents) the CPU time of the same binary varies by
+-15 % between runs, which hides a 5-10 % change in separate-process pairs. This timing build
renders every frame twice in one process, once with each loop form, in alternating order, so
both see the same load within ~0.1 s:

  vulkan_loop_ab_probe.py patch TREE OLD_SHADER [surface|sky]
    TREE: a copy of the sources (never the working tree) whose blend_shade.glsl has the new loop;
    OLD_SHADER: a blend_shade.glsl with another loop (e.g. `git show 7513250:shaders/blend_shade.glsl`);
    the loop is the text between the max_candidates cap and the blend of the best n (surface, the
    default) or ShadeBackground's view loop (sky).
    The surface loop becomes `if (kAbOld != 0) { old loop } else { new loop }` on specialisation
    constant 9 (BlendVariant bit 8: both pipelines are built, each holds one form), and vulkan_bench
    renders each frame with kAbOld = 0 and 1 and prints ab_cpu_new / ab_cpu_old (per-frame CPU ms)
    and the paired median of new / old.
Run e.g. `vulkan_bench --frames=20 --refs=16 --sizes=1280x720 --fill_holes=0 --pose=3`.
"""
import sys

# The loops the A/B can swap: the surface pass's reference loop (from after the max_candidates
# cap to the blend of the best n) and the background pass's view loop (ShadeBackground, from
# after the empty best-n to its blend).
REGIONS = {
    'surface': ('  if (frame.bg_params.y > 0) count = min(count, uint(frame.bg_params.y));\n',
                '  vec3 srgb;\n  const bool covered = BlendBest(best, n, srgb);'),
    'sky': ('  best.s0 = best.s1 = best.s2 = best.s3 = vec4(0.0);\n',
            '  vec3 srgb;\n  const bool filled = BlendBest(best, n, srgb);'),
}


def loop_span(s, region):
    start, end = REGIONS[region]
    j = s.index(end)
    i = s.rindex(start, 0, j) + len(start)
    return i, j


def rep(s, a, b):
    assert s.count(a) == 1, 'sources changed: update the probe: ' + a[:60]
    return s.replace(a, b)


def edit(path, pairs):
    s = open(path).read()
    for a, b in pairs:
        s = rep(s, a, b)
    open(path, 'w').write(s)


def patch(tree, old_shader, region='surface'):
    old = open(old_shader).read()
    i, j = loop_span(old, region)
    old_loop = old[i:j]
    p = tree + '/shaders/blend_shade.glsl'
    s = open(p).read()
    i, j = loop_span(s, region)
    s = s[:i] + 'if (kAbOld != 0) {\n' + old_loop + '} else {\n' + s[i:j] + '}\n' + s[j:]
    s = rep(s, 'layout(constant_id = 5) const int kBakedWeights = 0;',
            'layout(constant_id = 5) const int kBakedWeights = 0;\n'
            'layout(constant_id = 9) const int kAbOld = 0;')
    open(p, 'w').write(s)

    edit(tree + '/client/vulkan/vk_pipelines.h', [
        ('  bool default_weights = false;\n', '  bool default_weights = false;\n  bool ab_old = false;\n'),
        ('(default_weights ? 4 : 0);', '(default_weights ? 4 : 0) | (ab_old ? 8 : 0);'),
        ('static constexpr int kCount = 8;', 'static constexpr int kCount = 16;'),
    ])

    edit(tree + '/client/vulkan/vk_pipelines.cc', [
        ('int32_t values[8] = {n_best,', 'int32_t values[9] = {n_best,'),
        ('                       std::bit_cast<int32_t>(d.occlusion_epsilon_rel)};',
            '                       std::bit_cast<int32_t>(d.occlusion_epsilon_rel),\n'
            '                       v.ab_old ? 1 : 0};'),
        ('  VkSpecializationMapEntry entries[8];\n  const uint32_t ids[8] = {0, 1, 2, 3, 5, 6, 7, 8};\n'
               '  for (uint32_t k = 0; k < 8; ++k)',
            '  VkSpecializationMapEntry entries[9];\n  const uint32_t ids[9] = {0, 1, 2, 3, 5, 6, 7, 8, 9};\n'
            '  for (uint32_t k = 0; k < 9; ++k)'),
        ('VkSpecializationInfo spec{8, entries,', 'VkSpecializationInfo spec{9, entries,'),
    ])

    edit(tree + '/client/vulkan/vk_frame_renderer.cc', [
        ('  v.default_weights = BlendVariant::DefaultWeights(bo);\n',
            '  v.default_weights = BlendVariant::DefaultWeights(bo);\n  v.ab_old = g_ab_old != 0;\n'),
        ('namespace exo::vk {\n', 'namespace exo::vk {\nint g_ab_old = 0;\n'),
    ])

    edit(tree + '/client/vulkan/vulkan_bench.cc', [
        ('int main(int argc, char** argv) {',
            'namespace exo::vk { extern int g_ab_old; }\nint main(int argc, char** argv) {'),
        ('''        auto out = r->Render(cam, pose, bo, RenderApprox{max_candidates});
        const double cpu_ms = ProcessCpuMs() - c0;''',
            '''        // A/B: this frame with the other loop form first or after (order alternating).
        double ab_other_cpu = 0;
        auto ab_other = [&] {
          exo::vk::g_ab_old = 1;
          const double a0 = ProcessCpuMs();
          auto o = r->Render(cam, pose, bo, RenderApprox{max_candidates});
          ab_other_cpu = ProcessCpuMs() - a0;
          exo::vk::g_ab_old = 0;
          return o.ok();
        };
        if (k % 2 == 1 && !ab_other()) return 1;
        const double c0b = ProcessCpuMs();
        auto out = r->Render(cam, pose, bo, RenderApprox{max_candidates});
        const double cpu_ms = ProcessCpuMs() - c0b;
        if (k % 2 == 0 && !ab_other()) return 1;
        (void)c0;
        if (k > 0) { ab_new.push_back(cpu_ms); ab_old.push_back(ab_other_cpu); }'''),
        ('      int ssim_n = 0;\n', '      int ssim_n = 0;\n      std::vector<double> ab_new, ab_old;\n'),
        ('          {"median_rank_ms", Round(med(rank_v), 2)},',
            '''          {"median_rank_ms", Round(med(rank_v), 2)},
          {"ab_cpu_new", ab_new}, {"ab_cpu_old", ab_old},
          {"ab_median_cpu_new", Round(med(ab_new), 2)}, {"ab_median_cpu_old", Round(med(ab_old), 2)},
          {"ab_median_ratio_new_old", [&] { std::vector<double> q; for (size_t i = 0; i < ab_new.size(); ++i) q.push_back(ab_new[i] / ab_old[i]); return Round(med(q), 4); }()},'''),
    ])


if __name__ == '__main__':
    if len(sys.argv) in (4, 5) and sys.argv[1] == 'patch':
        patch(*sys.argv[2:])
    else:
        sys.exit(__doc__)
