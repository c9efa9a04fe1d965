// exoview_eval: the evaluation benchmark of SPEC §9. Prints one JSON object per configuration
// (config, quality, speed, memory) on stdout; progress on stderr. Flags: kUsage below (--help).
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <absl/strings/str_format.h>
#include <absl/strings/numbers.h>
#include <absl/strings/str_split.h>

#include <nlohmann/json.hpp>

#include "common/cli/cli.h"
#include "server/eval/eval.h"

namespace exo::eval {
namespace {

constexpr char kUsage[] =
    "exoview_eval: the evaluation benchmark of SPEC §9. Prints one JSON object per configuration\n"
    "(config, quality, speed, memory) on stdout; progress on stderr.\n"
    "\n"
    "  exoview_eval --suite quick|full [--out results.jsonl]      predefined runs (docs/evaluation.md)\n"
    "  exoview_eval --scene village --traj flyover|walk|drone|handheld --frames 600 --proxy tsdf|gt\n"
    "               --voxel 0\n"
    "               --test_views 200 --policies online,offline_greedy,every_n,min_distance,all\n"
    "               --store 200 --r_max 16 [--lambda 0.5] [--cell 0] [--dts 0.05]\n"
    "               [--sweep store|r_max|lambda|cell] [--sweep_test_views 50]\n"
    "               [--dump DIR --dump_views 4]\n"
    "  exoview_eval --sevenscenes DIR [--store 50] [--policies ...] [--register 0|1 (default 1:\n"
    "               depth registered to colour, docs/registration.md)]\n"
    "               [--holdout_offset J: hold out frame k when k mod 10 == J (default 9)]\n"
    "  --store N[,N...]      store size(s); the policies run at each (\"all\" once)\n"
    "  --blend_variants \"k=v,k=v;k=v\"  issue 15: per variant, the --variant_policies configs\n"
    "                        (default online) at --variant_store (default: first --store) rendered\n"
    "                        with the blend flags changed (keys: disc_r disc_m disc_rel occ_m occ_rel\n"
    "                        n_best positional; own_depth=1: each 7-Scenes test view's own depth is\n"
    "                        the proxy), tagged with the variant text; one ingest for all\n"
    "  --test_poses scene|near|scene,near   test pose set(s), all evaluated on the same stores\n"
    "  --look_around DEG     walk yaw-sweep amplitude (synth default 20)\n"
    "  --scene_seed N        synthetic scene seed (layout, textures; default 1), for replicates\n"
    "  --test_seed N         test-pose seed (default 7)\n"
    "  --face_areas 1        planners use the cell face area A_cell for every cell, not the proxy's\n"
    "                        CellAreas (A(b_k) of 3.13); policy online_final_areas (diagnostic):\n"
    "                        the online rules replayed after the stream on the final proxy's areas\n"
    "  --per_view 1          per-test-view SSIM, nearest stored view, reference hit in the JSON\n"
    "  --lod F               cell-id buffers from a vertex-clustered proxy LOD, clusters F x cell size\n"
    "                        (0: full proxy mesh; default -1: planning::DefaultCellIdLodM)\n"
    "  --lod_m M             cell-id LOD cluster size in metres (wins over --lod; held fixed across a\n"
    "                        voxel sweep)\n"
    "  --tag NAME            label of the policy configs in the JSON (default \"main\")\n"
    "  --lod_keep F          keep a chunk's LOD while its triangle count is within F (default 0.1)\n"
    "  --ids depth|proxy     psi_vis from the frame's own depth (default, as the server does) or\n"
    "                        from a render of the proxy (SPEC 3.12 as written)\n"
    "  --scale bounds|depth|server  d_max/σ from scene_scale.h, from the first frame's median depth,\n"
    "                 or the server's rule (core::ChooseSceneSetup on the first frame)\n"
    "                        (synthetic default bounds, 7-Scenes default depth)\n"
    "  policies every_n_uncapped, min_distance_uncapped, all_uncapped: baseline referencing every\n"
    "  selected observer per cell (no R_max cap); plain names use the planner's pre-selection\n"
    "  issue 22: --traj drone|handheld (seeded by --traj_seed, default the scene seed); online\n"
    "  baselines every_n_online (progressive decimation), reservoir (--policy_seed), keyframe\n"
    "  (--kf_threshold, InpaintFusion 0.7); every_n knows the length (an oracle, \"online\":0)\n";

struct Args {
  std::map<std::string, std::string> kv;
  std::string Get(const std::string& k, const std::string& d) const {
    auto it = kv.find(k);
    return it == kv.end() ? d : it->second;
  }
  double Num(const std::string& k, double d) const {
    auto it = kv.find(k);
    if (it == kv.end()) return d;
    double v = 0;
    if (!absl::SimpleAtod(it->second, &v)) {
      std::fprintf(stderr, "exoview_eval: %s needs a number, got '%s'\n", k.c_str(), it->second.c_str());
      std::exit(2);
    }
    return v;
  }
};

std::FILE* g_out = nullptr;
void Emit(const std::string& line) {
  std::printf("%s\n", line.c_str());
  std::fflush(stdout);
  if (g_out) {
    std::fprintf(g_out, "%s\n", line.c_str());
    std::fflush(g_out);
  }
}

absl::StatusOr<Policy> ParsePolicy(const std::string& s) {
  if (s == "online") return Policy::kOnline;
  if (s == "offline_greedy" || s == "offline") return Policy::kOfflineGreedy;
  if (s == "every_n") return Policy::kEveryN;
  if (s == "min_distance") return Policy::kMinDistance;
  if (s == "all" || s == "all_frames") return Policy::kAll;
  if (s == "online_final_areas") return Policy::kOnlineFinalAreas;
  if (s == "every_n_online") return Policy::kEveryNOnline;
  if (s == "reservoir") return Policy::kReservoir;
  if (s == "keyframe") return Policy::kKeyframe;
  return absl::InvalidArgumentError("unknown policy " + s);
}

// Configs of one run: the listed policies at (store, r_max, ...), plus an optional sweep of
// online configs over one parameter.
absl::StatusOr<std::vector<PolicyConfig>> Configs(const Args& a) {
  PolicyConfig base;
  // Sweeps use the first entry of the --store list; the policies every entry (below).
  base.store = std::atoi(std::string(*absl::StrSplit(a.Get("--store", "200"), ',').begin()).c_str());
  base.r_max = int(a.Num("--r_max", 16));
  base.render_refs_max = int(a.Num("--render_refs", 64));
  base.lambda = a.Num("--lambda", -1);
  base.cell_m = a.Num("--cell", 0);
  base.delta_tau_sum = a.Num("--dts", -1);
  base.tag = a.Get("--tag", "main");
  base.face_areas = a.Num("--face_areas", 0) != 0;
  base.policy_seed = uint64_t(a.Num("--policy_seed", 1));
  base.novelty_positional = a.Num("--novelty_positional", 0) != 0;  // also the sweeps' configs
  base.keyframe_threshold = a.Num("--kf_threshold", 0.7);
  if (!(base.keyframe_threshold > 0))
    return absl::InvalidArgumentError("--kf_threshold must be > 0");
  std::vector<PolicyConfig> out;
  // --store 50,100,200: the policies at each store size ("all" once: it has no store bound).
  std::vector<int> stores;
  for (absl::string_view st : absl::StrSplit(a.Get("--store", "200"), ',', absl::SkipEmpty()))
    stores.push_back(std::stoi(std::string(st)));
  if (stores.empty()) return absl::InvalidArgumentError("--store: no value");
  for (int store : stores)
  for (absl::string_view p : absl::StrSplit(a.Get("--policies", "online"), ',', absl::SkipEmpty())) {
    PolicyConfig c = base;
    c.store = store;
    std::string name(p);
    // Issue 22: "online_novelty" = the online planner with PlannerOptions::novelty_positional.
    if (name == "online_novelty") {
      c.novelty_positional = true;
      name = "online";
    }
    // "<policy>:lambda=V" / ":tau_max=V": that policy with one planner option changed, tagged
    // "lambda=V" (e.g. --policies online,online:lambda=1 compares two lambdas on one ingest).
    // Several options: "online:lambda=1+blend_lambda=0.4".
    if (const size_t colon = name.find(':'); colon != std::string::npos) {
      const std::string opts = name.substr(colon + 1);
      name.resize(colon);
      for (absl::string_view kvv : absl::StrSplit(opts, '+', absl::SkipEmpty())) {
        const std::string kv(kvv);
        const size_t eq = kv.find('=');
        double v = 0;
        if (eq == std::string::npos || !absl::SimpleAtod(kv.substr(eq + 1), &v))
          return absl::InvalidArgumentError("policy option must be key=value, got " + kv);
        const std::string key = kv.substr(0, eq);
        if (key == "lambda") c.lambda = v;
        else if (key == "blend_lambda") c.blend_lambda = v;
        else if (key == "tau_max") c.tau_max = v;
        else if (key == "soft") c.soft_saturation = v != 0;
        else if (key == "disp") {
          if (v != 0 && v != 1 && v != 2)
            return absl::InvalidArgumentError("disp must be 0 (off), 1 (ties) or 2 (first)");
          c.dispersion = static_cast<int>(v);
        } else if (key == "dg") c.dispersion_guard = v;
        else if (key == "dgr") c.dispersion_guard_relative = v;
        else if (key == "dgu") c.dispersion_guard_unique = v != 0 ? 1 : 0;
        else if (key == "dgua") c.dispersion_guard_unique_after = v;
        else if (key == "dwe") c.dispersion_weight_exponent = v;
        else if (key == "dwa") c.dispersion_weight_after = v;
        else if (key == "dwu") c.dispersion_weight_until = v;
        else if (key == "dkn") c.dispersion_keep_nearest = v != 0 ? 1 : 0;
        else if (key == "drc") c.dispersion_recency = v;
        else if (key == "ddo") c.dispersion_drop_older = v != 0 ? 1 : 0;
        else if (key == "dtk") c.dispersion_time_steps = v;
        else if (key == "dtm") c.dispersion_time_max = v != 0 ? 1 : 0;
        else if (key == "dta") c.dispersion_time_arc = v != 0 ? 1 : 0;
        else if (key == "dtr") c.dispersion_time_auto_ref = v;
        else if (key == "ozc") c.observe_zero_coverage = v != 0 ? 1 : 0;
        else if (key == "rpl") c.replay_refs = v != 0;
        else if (key == "mpr") c.dispersion_m_per_rad = v;
        else if (key == "drs") c.dispersion_rotation_scale = v;
        else if (key == "dfo") c.dispersion_turn_overlap_deg = v;
        else if (key == "dfs") c.dispersion_turn_overlap_scale = v;
        else if (key == "dax") c.dispersion_turn_axis = v != 0 ? 1 : 0;
        else if (key == "dts") c.delta_tau_sum = v;
        else if (key == "sharp") c.sharp_gamma = v;
        else
          return absl::InvalidArgumentError("unknown policy option " + key +
                                            " (lambda, blend_lambda, tau_max, soft, sharp, disp, mpr, dg, dgr, dgu, dgua, dwe, dwa, dwu, dkn, drc, ddo, ozc, rpl, drs, dfo, dfs, dax, dts)");
      }
      c.tag = opts;
    }
    // "<baseline>_uncapped": R(b_k) = every selected observer instead of the fair pre-selection.
    if (name.size() > 9 && name.substr(name.size() - 9) == "_uncapped") {
      c.uncapped_refs = true;
      name.resize(name.size() - 9);
    }
    EXO_ASSIGN_OR_RETURN(c.policy, ParsePolicy(name));
    if (c.policy == Policy::kAll && store != stores.front()) continue;
    out.push_back(c);
  }
  const int btv = int(a.Num("--baseline_test_views", -1));
  for (PolicyConfig& c : out)
    if (c.policy != Policy::kOnline && c.policy != Policy::kOfflineGreedy) c.test_views = btv;
  const int stv = int(a.Num("--sweep_test_views", -1));
  for (absl::string_view sw : absl::StrSplit(a.Get("--sweep", ""), ',', absl::SkipEmpty())) {
    const std::string sweep(sw);
    auto add = [&](auto set, std::vector<double> values) {
      for (double v : values) {
        PolicyConfig c = base;
        c.policy = Policy::kOnline;
        c.tag = "sweep_" + sweep;
        c.test_views = stv;
        set(c, v);
        out.push_back(c);
      }
    };
    if (sweep == "store") add([](PolicyConfig& c, double v) { c.store = int(v); }, {25, 50, 100, 200, 400});
    else if (sweep == "r_max") add([](PolicyConfig& c, double v) { c.r_max = int(v); }, {4, 8, 16, 32});
    else if (sweep == "lambda") add([](PolicyConfig& c, double v) { c.lambda = v; }, {0.0, 0.2, 0.4, 0.6, 0.8, 1.0});
    else if (sweep == "cell") add([](PolicyConfig& c, double v) { c.cell_m = v; }, {0.3, 0.5, 1.0, 2.0});
    else if (sweep == "tau_max") add([](PolicyConfig& c, double v) { c.tau_max = v; }, {2, 4, 8, 16, 64});
    else if (sweep == "render_refs") add([](PolicyConfig& c, double v) { c.render_refs_max = int(v); }, {0, 16, 32, 64});
    else if (sweep == "dts") add([](PolicyConfig& c, double v) { c.delta_tau_sum = v; }, {0.0, 0.5, 2.0, 8.0});
    else return absl::InvalidArgumentError("unknown sweep " + sweep);
  }
  return out;
}

blend::BlendOptions Blend(const Args& a) {
  blend::BlendOptions b;
  b.positional_mode = a.Get("--positional", "ulr") == "printed" ? blend::PositionalMode::kPrinted
                                                                : blend::PositionalMode::kUlrResolution;
  b.discontinuity_radius_px = int(a.Num("--disc_r", b.discontinuity_radius_px));
  b.discontinuity_delta_z_m = float(a.Num("--disc_m", b.discontinuity_delta_z_m));
  b.discontinuity_delta_z_rel = float(a.Num("--disc_rel", b.discontinuity_delta_z_rel));
  b.occlusion_epsilon_m = float(a.Num("--occ_m", b.occlusion_epsilon_m));
  b.occlusion_epsilon_rel = float(a.Num("--occ_rel", b.occlusion_epsilon_rel));
  b.n_best = int(a.Num("--n_best", b.n_best));
  return b;
}

// Issue 15: --blend_variants "soft_vis=0.05;photo=0.1,n_best=4" adds, per variant, a copy of
// the --variant_policies configs (default online) at --variant_store (default: first --store)
// rendered with the run's blend options changed by the variant's key=value pairs (keys are the
// blend flags without "--"), tagged with the variant text.
absl::Status AddBlendVariants(const Args& a, std::vector<PolicyConfig>* configs) {
  const std::string spec = a.Get("--blend_variants", "");
  if (spec.empty()) return absl::OkStatus();
  Args va = a;
  va.kv["--policies"] = a.Get("--variant_policies", "online");
  va.kv["--store"] = a.Get("--variant_store", std::string(*absl::StrSplit(a.Get("--store", "200"), ',').begin()));
  va.kv.erase("--blend_variants");
  for (absl::string_view v : absl::StrSplit(spec, ';', absl::SkipEmpty())) {
    Args b = a;
    for (absl::string_view kv : absl::StrSplit(v, ',', absl::SkipEmpty())) {
      std::vector<std::string> p = absl::StrSplit(kv, '=');
      if (p.size() != 2) return absl::InvalidArgumentError("--blend_variants: bad pair " + std::string(kv));
      b.kv["--" + p[0]] = p[1];
    }
    auto base = Configs(va);
    if (!base.ok()) return base.status();
    for (PolicyConfig c : *base) {
      c.blend = Blend(b);
      c.own_depth_proxy = b.Num("--own_depth", 0) != 0;
      EXO_RETURN_IF_ERROR(c.blend->Validate());
      c.tag = std::string(v);
      configs->push_back(c);
    }
  }
  return absl::OkStatus();
}

int RunOne(const Args& a) {
  auto configs = Configs(a);
  if (configs.ok()) {
    if (absl::Status st = AddBlendVariants(a, &*configs); !st.ok()) configs = st;
  }
  if (!configs.ok()) {
    std::fprintf(stderr, "%s\n", std::string(configs.status().message()).c_str());
    return 2;
  }
  if (a.kv.count("--sevenscenes")) {
    SevenScenesRunOptions o;
    o.dir = a.Get("--sevenscenes", "");
    o.max_frames = int(a.Num("--frames", 0));
    o.register_depth = a.Num("--register", 1) != 0;
    o.holdout_offset = int(a.Num("--holdout_offset", -1));  // issue 15 folds
    o.voxel_m = a.Num("--voxel", 0);
    o.test_width = int(a.Num("--test_w", 640));
    o.test_height = int(a.Num("--test_h", 480));
    o.test_box = a.Num("--test_box", 0) != 0;
    o.cellid_lod_frac = a.Num("--lod", o.cellid_lod_frac);
    o.cellid_lod_m = a.Num("--lod_m", o.cellid_lod_m);
    o.cellid_lod_keep = a.Num("--lod_keep", o.cellid_lod_keep);
    if (a.kv.count("--ids")) o.cell_ids = a.Get("--ids", "") == "proxy" ? CellIdSource::kProxy : CellIdSource::kFrameDepth;
    o.per_view = a.Num("--per_view", 0) != 0;
    if (a.kv.count("--scale") && !ParseScaleMode(a.Get("--scale", ""), &o.scale_mode)) {
      std::fprintf(stderr, "unknown --scale %s (bounds | depth | server)\n", a.Get("--scale", "").c_str());
      return 2;
    }
    o.blend = Blend(a);
    o.configs = *configs;
    o.emit = Emit;
    o.dump_dir = a.Get("--dump", "");
    o.dump_views = int(a.Num("--dump_views", 0));
    auto rep = RunSevenScenes(o);
    if (!rep.ok()) {
      std::fprintf(stderr, "%s\n", std::string(rep.status().message()).c_str());
      return 1;
    }
    nlohmann::ordered_json split;
    split["bench"] = "eval_split";
    split["dataset"] = "7scenes/redkitchen";
    split["registered"] = o.register_depth ? 1 : 0;
    split["ingested"] = rep->ingested;
    split["held_out"] = rep->held_out;
    split["dropped_duplicate_colour"] = rep->dropped_duplicates;
    split["test_views"] = rep->held_out - rep->dropped_duplicates;
    split["holdout_offset"] = o.holdout_offset < 0 ? o.hold_out_every - 1 : o.holdout_offset;
    Emit(split.dump());
    return 0;
  }
  SynthRunOptions o;
  o.scene = a.Get("--scene", "village");
  o.traj = a.Get("--traj", o.scene == "apartment" ? "walk" : "flyover");
  o.frames = int(a.Num("--frames", 600));
  o.proxy = a.Get("--proxy", "tsdf") == "gt" ? ProxyKind::kGroundTruth : ProxyKind::kTsdf;
  o.voxel_m = a.Num("--voxel", 0);
  o.test_views = int(a.Num("--test_views", 200));
  o.scene_seed = uint64_t(a.Num("--scene_seed", 1));
  o.traj_seed = int64_t(a.Num("--traj_seed", -1));
  o.frame_width = int(a.Num("--frame_w", 640));
  o.frame_height = int(a.Num("--frame_h", 480));
  o.test_seed = uint64_t(a.Num("--test_seed", 7));
  o.test_width = int(a.Num("--test_w", 320));
  o.test_height = int(a.Num("--test_h", 240));
  o.id_width = int(a.Num("--idw", 160));
  o.id_height = int(a.Num("--idh", 120));
  o.cellid_lod_frac = a.Num("--lod", o.cellid_lod_frac);
  o.cellid_lod_m = a.Num("--lod_m", o.cellid_lod_m);
  o.cellid_lod_keep = a.Num("--lod_keep", o.cellid_lod_keep);
  if (a.kv.count("--ids")) o.cell_ids = a.Get("--ids", "") == "proxy" ? CellIdSource::kProxy : CellIdSource::kFrameDepth;
  o.blend = Blend(a);
  // --test_poses scene | near | scene,near (both sets on the same stream and stores)
  for (absl::string_view m : absl::StrSplit(a.Get("--test_poses", "scene"), ',', absl::SkipEmpty())) {
    if (m == "near") o.test_pose_modes.push_back(TestPoseMode::kNearTrajectory);
    else if (m == "scene") o.test_pose_modes.push_back(TestPoseMode::kSceneWide);
    else {
      std::fprintf(stderr, "unknown --test_poses %s\n", std::string(m).c_str());
      return 2;
    }
  }
  o.walk_look_around_deg = a.Num("--look_around", -1);
  o.per_view = a.Num("--per_view", 0) != 0;
  o.vertex_color_baseline = a.Num("--vertex_color", 1) != 0;
  if (a.kv.count("--scale") && !ParseScaleMode(a.Get("--scale", ""), &o.scale_mode)) {
    std::fprintf(stderr, "unknown --scale %s (bounds | depth | server)\n", a.Get("--scale", "").c_str());
    return 2;
  }
  o.configs = *configs;
  o.emit = Emit;
  o.dump_dir = a.Get("--dump", "");
  o.dump_views = int(a.Num("--dump_views", 0));
  auto r = RunSynthetic(o);
  if (!r.ok()) {
    std::fprintf(stderr, "%s\n", std::string(r.status().message()).c_str());
    return 1;
  }
  return 0;
}

// Predefined suites: each entry is one RunOne argument list.
std::vector<std::vector<std::string>> Suite(const std::string& name, const std::string& data) {
  const std::string all = "online,offline_greedy,every_n,min_distance,all";
  if (name == "quick") {
    return {{"--scene", "apartment", "--traj", "walk", "--frames", "60", "--store", "20",
             "--test_views", "6", "--test_w", "160", "--test_h", "120", "--policies",
             "online,every_n"}};
  }
  // full: exactly the runs of docs/evaluation.md, in priority order: main comparison on both
  // scenes (scene-wide test poses, every bounded policy on the same 200 poses), 7-Scenes
  // hold-out, sweeps (200 frames, 20 test views), all-frames vs online on the ground-truth proxy
  // (20 views: rendering from every frame is slow), near-trajectory test poses (50 views).
  std::vector<std::vector<std::string>> s;
  const std::string bounded = "online,offline_greedy,every_n,min_distance";
  s.push_back({"--scene", "village", "--frames", "400", "--policies", bounded, "--store", "200",
               "--test_views", "200"});
  s.push_back({"--scene", "apartment", "--frames", "400", "--voxel", "0.04", "--policies",
               bounded, "--store", "200", "--test_views", "200"});
  if (!data.empty())
    s.push_back({"--sevenscenes", data + "/7scenes-redkitchen", "--store", "50", "--policies",
                 all + ",every_n_uncapped,min_distance_uncapped"});
  for (const char* sc : {"apartment", "village"})
    s.push_back({"--scene", sc, "--frames", "200", "--policies", "", "--sweep",
                 "store,r_max,dts,lambda,cell", "--test_views", "20", "--vertex_color", "0"});
  s.push_back({"--scene", "village", "--frames", "400", "--proxy", "gt", "--policies",
               "online,all", "--store", "100", "--test_views", "20"});
  for (const char* sc : {"village", "apartment"})
    s.push_back({"--scene", sc, "--frames", "300", "--voxel", sc == std::string("village") ? "0.15" : "0.04",
                 "--policies", "online,offline_greedy", "--store", "200", "--test_views", "50",
                 "--test_poses", "near"});
  return s;
}

// Every flag of RunOne / the suites with its help text (values are kept as text in Args; the
// suites build Args the same way).
constexpr std::pair<const char*, const char*> kFlags[] = {
    {"--suite", "quick | full: predefined runs (docs/evaluation.md)"},
    {"--out", "also write the JSON lines to this file"},
    {"--data", "data directory of the full suite (default $EXOVIEW_SHARED_DIR/data)"},
    {"--sevenscenes", "7-Scenes sequence directory (every 10th frame held out)"},
    {"--register", "7-Scenes: 1 (default) depth registered to colour, 0 raw"},
    {"--scene", "village | apartment"},
    {"--traj", "flyover | walk | drone | handheld"},
    {"--traj_seed", "drone / handheld stream seed (default: the scene seed)"},
    {"--frame_w", "synthetic input frame width (default 640)"},
    {"--frame_h", "synthetic input frame height (default 480)"},
    {"--policy_seed", "reservoir sampling seed (default 1)"},
    {"--novelty_positional", "1: every planner uses the novelty-weighted positional term (issue 22)"},
    {"--kf_threshold", "keyframe policy: ||I - M_i^-1 M_k||_F threshold (default 0.7)"},
    {"--frames", "input frames (7-Scenes: 0 = all)"},
    {"--proxy", "tsdf | gt"},
    {"--voxel", "TSDF voxel (m); 0 = the online model's rule (server/core)"},
    {"--test_views", "synthetic test poses"},
    {"--test_w", "test image width"},
    {"--test_h", "test image height"},
    {"--test_box", "1: 7-Scenes ground truth box-averaged to the test size (the product eval's reference) instead of nearest samples"},
    {"--test_poses", "scene | near | scene,near"},
    {"--test_seed", "test-pose seed (default 7)"},
    {"--scene_seed", "synthetic scene seed (default 1)"},
    {"--look_around", "walk yaw-sweep amplitude (deg)"},
    {"--idw", "cell-id buffer width"},
    {"--idh", "cell-id buffer height"},
    {"--policies", "online,offline_greedy,every_n,min_distance,all,every_n_online,reservoir,keyframe"
                   "[,*_uncapped,online_final_areas]"},
    {"--store", "store size (views)"},
    {"--r_max", "R_max"},
    {"--render_refs", "references per cell rendered (0 = R(b_k); N = every stored observer, at most N; default 64)"},
    {"--lambda", "planner lambda (< 0: 0.5 fly-over, 0.4 walk / real)"},
    {"--cell", "cell size (m); 0 = scene-scale rule"},
    {"--dts", "delta tau_sum"},
    {"--tag", "label of the policy configs in the JSON (default main)"},
    {"--face_areas", "1: planners use the face area A_cell for every cell"},
    {"--sweep", "store,r_max,lambda,cell,dts,tau_max,render_refs"},
    {"--sweep_test_views", "test views of sweep configs"},
    {"--baseline_test_views", "test views of baseline configs"},
    {"--per_view", "1: per-test-view diagnostics in the JSON"},
    {"--lod", "cell-id LOD cluster size as a fraction of the cell (-1 default, 0 full mesh)"},
    {"--lod_m", "cell-id LOD cluster size in metres (wins over --lod)"},
    {"--lod_keep", "keep a chunk's LOD within this triangle-count change (default 0.1)"},
    {"--ids", "depth | proxy: where psi_vis comes from"},
    {"--scale", "bounds | depth | server: d_max / sigma (/ cell) rule"},
    {"--vertex_color", "0: no vertex-colour baseline"},
    {"--dump", "directory for render/GT/coverage PNGs"},
    {"--dump_views", "how many views to dump"},
    {"--positional", "ulr | printed"},
    {"--disc_r", "blend: discontinuity radius (px)"},
    {"--disc_m", "blend: discontinuity delta z (m)"},
    {"--disc_rel", "blend: relative discontinuity delta z"},
    {"--occ_m", "blend: occlusion epsilon (m)"},
    {"--occ_rel", "blend: relative occlusion epsilon"},
    {"--n_best", "blend: n best views"},
    {"--holdout_offset", "7-Scenes fold J: frames i % 10 == J held out (default 9)"},
    {"--blend_variants",
     "extra configs with changed blend options on the same stream and stores: \"k=v,k=v;...\" "
     "(keys disc_r disc_m disc_rel occ_m occ_rel n_best positional own_depth)"},
    {"--variant_policies", "policies the blend variants are rendered for (default online)"},
    {"--variant_store", "store size the blend variants are rendered at"},
};

}  // namespace
}  // namespace exo::eval

int main(int argc, char** argv) {
  using namespace exo::eval;
  CLI::App app{std::string(kUsage), "exoview_eval"};
  exo::cli::Setup(app);
  std::map<std::string, std::string> values;
  for (const auto& [name, help] : kFlags) app.add_option(name, values[name], help);
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  Args a;
  for (const auto& [name, help] : kFlags)
    if (app.count(name) > 0) a.kv[name] = values[name];
  if (a.kv.count("--out")) g_out = std::fopen(a.Get("--out", "").c_str(), "w");
  const std::string suite = a.Get("--suite", "");
  if (suite.empty()) return RunOne(a);
  std::string data = a.Get("--data", "");
  if (data.empty()) {
    const char* env = std::getenv("EXOVIEW_SHARED_DIR");
    data = env ? std::string(env) + "/data" : "";
  }
  int rc = 0;
  for (const auto& run : Suite(suite, data)) {
    Args r;
    for (size_t i = 0; i + 1 < run.size(); i += 2) r.kv[run[i]] = run[i + 1];
    std::string line;
    for (const auto& s : run) line += s + " ";
    std::fprintf(stderr, "== %s\n", line.c_str());
    rc |= RunOne(r);
  }
  if (g_out) std::fclose(g_out);
  return rc;
}
