#include "server/service/control_service.h"

#include "server/service/auth.h"

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <cmath>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"
#include "common/io/jpeg.h"
#include "common/log/log.h"
#include "proto/control.grpc.pb.h"
#include "proto/frame_proto.h"
#include "server/service/model_store.h"
#include "server/service/server.h"

namespace exo {
namespace {

namespace cv1 = exoview::control::v1;
using control::InteractionKind;

double NowS() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

glm::dvec3 FromProto(const cv1::Vec3& v) { return {v.x(), v.y(), v.z()}; }
void ToProto(const glm::dvec3& v, cv1::Vec3* out) {
  out->set_x(v.x);
  out->set_y(v.y);
  out->set_z(v.z);
}

grpc::Status ToGrpc(const absl::Status& s) {
  return grpc::Status(static_cast<grpc::StatusCode>(s.code()), std::string(s.message()));
}

// `principal` "" = no authentication: the header's operator id as sent.
control::Command CommandOf(const cv1::OperatorHeader& h, const std::string& principal) {
  return {principal.empty() ? h.operator_id() : principal, h.operator_sequence(),
          h.drone_id().empty() ? "drone" : h.drone_id()};
}

void FillReply(const control::CommandResult& r, cv1::InteractionReply* out) {
  out->set_command_sequence(r.command_sequence);
  out->set_interaction(static_cast<cv1::Interaction>(r.kind));
  ToProto(r.target.position, out->mutable_target());
  out->set_target_yaw(r.target.yaw);
  out->set_clamped(r.route.clamped);
  for (const auto& w : r.route.waypoints) ToProto(w, out->add_waypoints());
  out->set_note(r.note);
  out->set_route_length_m(r.route.length_m);
  out->set_camera_pitch(r.target.camera_pitch);
  if (r.gaze) {
    out->set_has_gaze(true);
    ToProto(r.gaze->hit.point, out->mutable_gaze_point());
    ToProto(r.gaze->hit.normal, out->mutable_gaze_normal());
    out->set_horizontal_surface(r.gaze->horizontal_surface);
  }
}

// "x,y,z" -> vector.
absl::StatusOr<glm::dvec3> ParseVec3(const std::string& key, absl::string_view text) {
  const std::vector<std::string> p = absl::StrSplit(text, ',');
  glm::dvec3 v;
  if (p.size() != 3 || !absl::SimpleAtod(absl::StripAsciiWhitespace(p[0]), &v.x) ||
      !absl::SimpleAtod(absl::StripAsciiWhitespace(p[1]), &v.y) ||
      !absl::SimpleAtod(absl::StripAsciiWhitespace(p[2]), &v.z))
    return absl::InvalidArgumentError(absl::StrCat("config ", key, ": '", text, "' is not x,y,z"));
  return v;
}

std::string Vec3Text(const glm::dvec3& v) { return absl::StrCat(v.x, ",", v.y, ",", v.z); }

// A number key: > 0, or >= 0 with `zero_ok` (0 then means off).
ConfigKey DoubleKey(std::string name, std::string help, double* (*field)(ServerConfig&),
                    bool zero_ok = false) {
  ConfigKey k;
  k.name = name;
  k.help = std::move(help);
  k.get = [field](const ServerConfig& c) {
    return absl::StrCat(*field(const_cast<ServerConfig&>(c)));
  };
  k.set = [field, name, zero_ok](const std::string& v, ServerConfig* c) {
    double x;
    if (!absl::SimpleAtod(v, &x) || !std::isfinite(x) || !(zero_ok ? x >= 0 : x > 0))
      return absl::InvalidArgumentError(absl::StrCat(
          "config ", name, ": '", v, "' is not a ", zero_ok ? "non-negative" : "positive",
          " number"));
    *field(*c) = x;
    return absl::OkStatus();
  };
  return k;
}

// An angle key in radians within [-pi/2, pi/2] (an elevation: negative is below the horizon).
ConfigKey ElevationKey(std::string name, std::string help, double* (*field)(ServerConfig&)) {
  ConfigKey k = DoubleKey(name, std::move(help), field);
  k.set = [field, name](const std::string& v, ServerConfig* c) {
    double x;
    if (!absl::SimpleAtod(v, &x) || !(std::abs(x) <= control::kPi / 2))
      return absl::InvalidArgumentError(
          absl::StrCat("config ", name, ": '", v, "' is not an angle in [-pi/2, pi/2] rad"));
    *field(*c) = x;
    return absl::OkStatus();
  };
  return k;
}

ConfigKey BoolKey(std::string name, std::string help, bool* (*field)(ServerConfig&)) {
  ConfigKey k;
  k.name = name;
  k.help = std::move(help);
  k.get = [field](const ServerConfig& c) {
    return std::string(*field(const_cast<ServerConfig&>(c)) ? "true" : "false");
  };
  k.set = [field, name](const std::string& v, ServerConfig* c) {
    bool b;
    if (!absl::SimpleAtob(v, &b))
      return absl::InvalidArgumentError(
          absl::StrCat("config ", name, ": '", v, "' is not true or false"));
    *field(*c) = b;
    return absl::OkStatus();
  };
  return k;
}

}  // namespace

void AppendControlConfigKeys(std::vector<ConfigKey>* keys) {
  ConfigKey zones;
  zones.name = "control_zones";
  zones.help =
      "drone flight zones separated by ';' (world frame; empty: no control service): boxes "
      "'name:minx,miny,minz,maxx,maxy,maxz' or prisms 'name:poly<x|y|z>:floor,ceiling:u1,v1,u2,v2,"
      "u3,v3,...' (a polygon over the two other axes, floor and ceiling along the named one)";
  zones.get = [](const ServerConfig& c) {
    std::string s;
    for (const auto& z : c.control.core.safe.zones) {
      if (z.vertical_axis >= 0)
        absl::StrAppend(&s, s.empty() ? "" : ";", control::ZoneText(z));
      else
        absl::StrAppend(&s, s.empty() ? "" : ";", z.name, ":", Vec3Text(z.min), ",",
                        Vec3Text(z.max));
    }
    return s;
  };
  zones.set = [](const std::string& v, ServerConfig* c) -> absl::Status {
    std::vector<control::Zone> out;
    for (absl::string_view part : absl::StrSplit(v, ';', absl::SkipWhitespace())) {
      auto z = control::ParseZone(std::string(part));
      if (!z.ok())
        return absl::InvalidArgumentError(
            absl::StrCat("config control_zones: ", z.status().message()));
      out.push_back(*z);
    }
    c->control.core.safe.zones = std::move(out);
    return absl::OkStatus();
  };
  keys->push_back(std::move(zones));

  ConfigKey portals;
  portals.name = "control_portals";
  portals.help = "region waypoints joining zones before anything is modelled, 'x,y,z;x,y,z'";
  portals.get = [](const ServerConfig& c) {
    std::string s;
    for (const auto& p : c.control.core.safe.portals)
      absl::StrAppend(&s, s.empty() ? "" : ";", Vec3Text(p));
    return s;
  };
  portals.set = [](const std::string& v, ServerConfig* c) -> absl::Status {
    std::vector<glm::dvec3> out;
    for (absl::string_view part : absl::StrSplit(v, ';', absl::SkipWhitespace())) {
      EXO_ASSIGN_OR_RETURN(glm::dvec3 p, ParseVec3("control_portals", part));
      out.push_back(p);
    }
    c->control.core.safe.portals = std::move(out);
    return absl::OkStatus();
  };
  keys->push_back(std::move(portals));

  ConfigKey up;
  up.name = "control_up";
  up.help = "the scene's up axis x,y,z (7-Scenes: 0,-1,0)";
  up.get = [](const ServerConfig& c) { return Vec3Text(c.control.core.up); };
  up.set = [](const std::string& v, ServerConfig* c) -> absl::Status {
    EXO_ASSIGN_OR_RETURN(glm::dvec3 u, ParseVec3("control_up", v));
    if (!control::SceneFrame::FromUp(u).ok())
      return absl::InvalidArgumentError("config control_up: must be a non-zero vector");
    c->control.core.up = u;
    return absl::OkStatus();
  };
  keys->push_back(std::move(up));

  keys->push_back(DoubleKey("control_cell_m", "occupancy cell of safe flight in m",
                            [](ServerConfig& c) { return &c.control.core.safe.cell_m; }));
  keys->push_back(DoubleKey("control_drone_radius_m", "drone radius kept from obstacles in m",
                            [](ServerConfig& c) { return &c.control.core.safe.drone_radius_m; }));
  keys->push_back(DoubleKey("control_gaze_offset_m", "gaze-to-see distance x from the surface",
                            [](ServerConfig& c) { return &c.control.core.gaze.offset_m; }));
  keys->push_back(DoubleKey("control_setpoint_rate_hz", "setpoint repetition rate per drone",
                            [](ServerConfig& c) { return &c.control.core.setpoint_rate_hz; }));
  keys->push_back(DoubleKey("control_waypoint_tolerance_m",
                            "distance at which the next waypoint is streamed",
                            [](ServerConfig& c) { return &c.control.core.waypoint_tolerance_m; }));
  // The scale of exploration (docs/control.md, session 12: the defaults are a room's; a 60 m
  // village needs d_max ~14 m, sigma ~18 m and a 30 m range, as scene_scale.h derives them).
  keys->push_back(DoubleKey("control_carve_range_m",
                            "stored views' depth beyond this carves no free space, in m",
                            [](ServerConfig& c) { return &c.control.core.carve_max_range_m; }));
  keys->push_back(DoubleKey("control_explore_range_m",
                            "exploration: frustum ray length of a view's expected gain, in m",
                            [](ServerConfig& c) { return &c.control.core.explore.range_m; }));
  keys->push_back(DoubleKey("control_explore_d_max_m",
                            "exploration: ideal view distance d_max of (3.11), in m",
                            [](ServerConfig& c) { return &c.control.core.explore.d_max_m; }));
  keys->push_back(DoubleKey("control_explore_sigma_m",
                            "exploration: sigma of (3.11), in m",
                            [](ServerConfig& c) { return &c.control.core.explore.sigma_m; }));
  // Outdoor scenes (docs/control.md, sessions 14-15): a sweep over the zones' footprint as the
  // autonomous mode's fallback while its best view's gain is mostly unknown space.
  keys->push_back(DoubleKey(
      "control_explore_sweep_altitude_m",
      "exploration: sweep the zones' footprint (a Hilbert curve, 64 points, inset 15 %) at this "
      "height along control_up while the best view's gain is mostly unknown space; 0: no sweep",
      [](ServerConfig& c) { return &c.control.core.explore_sweep_altitude_m; }, true));
  keys->push_back(BoolKey(
      "control_explore_sweep_climb",
      "exploration: look at a sweep point above the air seen so far before climbing to it "
      "(false: fly to the highest reachable cell under it)",
      [](ServerConfig& c) { return &c.control.core.explore.sweep_climb; }));
  keys->push_back(DoubleKey(
      "control_explore_sweep_pass_m",
      "exploration: sweep points at the sweep's altitude are passed through within this "
      "distance, not hovered at, in m; 0: hovered at",
      [](ServerConfig& c) { return &c.control.core.explore.sweep_pass_m; }, true));
  keys->push_back(DoubleKey(
      "control_explore_sweep_look_dwell_s",
      "exploration: the hover at a look before a climb to a sweep point, in s (the usual "
      "hover elsewhere: 1 s)",
      [](ServerConfig& c) { return &c.control.core.explore.sweep_look_dwell_s; }, true));
  keys->push_back(BoolKey(
      "control_carve_no_return",
      "pixels without depth carve free space up to control_carve_range_m (a simulated sky; "
      "off for real sensors, whose black or specular surfaces return nothing too)",
      [](ServerConfig& c) { return &c.control.core.carve_no_return; }));
  // A sky rule for real sensors (docs/control.md, sessions 16-17): OccupancyGrid::SkyRule with
  // the stored view's JPEG colour.
  keys->push_back(BoolKey(
      "control_carve_sky_rule",
      "pixels without depth carve free space up to control_carve_range_m only where they look "
      "like sky: above control_carve_sky_min_elevation_rad, nothing measured above them in their "
      "image column, bright and blue in the view's colour (not with control_carve_no_return)",
      [](ServerConfig& c) { return &c.control.core.carve_sky_rule; }));
  keys->push_back(ElevationKey(
      "control_carve_sky_min_elevation_rad",
      "control_carve_sky_rule: the lowest ray elevation above the horizon (along control_up) a "
      "missing depth is taken as sky at, in rad; negative: below the horizon",
      [](ServerConfig& c) { return &c.control.core.carve_sky_min_elevation_rad; }));
}

// ---------------------------------------------------------------------------------------------

class ControlServiceHost::Impl final : public cv1::Control::Service {
 public:
  Impl(control::ControlCore* core, AuthorizeFn authorize)
      : core_(core), authorize_(std::move(authorize)) {}

  grpc::Status DroneLink(
      grpc::ServerContext* ctx,
      grpc::ServerReaderWriter<cv1::Setpoint, cv1::DroneState>* stream) override {
    if (auto who = Authorize(*ctx, Rpc::kDroneLink); !who.ok()) return ToGrpc(who.status());
    links_.fetch_add(1);
    std::string id;
    cv1::DroneState msg;
    while (stream->Read(&msg)) {
      if (id.empty()) {
        id = msg.drone_id().empty() ? "drone" : msg.drone_id();
        log_->info("drone link opened: drone={} peer={}", id, ctx->peer());
      }
      control::DroneState s;
      s.timestamp_s = msg.timestamp_s();
      s.position = FromProto(msg.position());
      s.velocity = FromProto(msg.velocity());
      s.yaw = msg.yaw();
      s.camera_pitch = msg.camera_pitch();
      const double now = NowS();
      core_->OnDroneState(id, s, now);
      if (auto sp = core_->NextSetpoint(id, now)) {
        cv1::Setpoint out;
        out.set_sequence(sp->sequence);
        ToProto(sp->setpoint.position, out.mutable_position());
        out.set_yaw(sp->setpoint.yaw);
        out.set_camera_pitch(sp->setpoint.camera_pitch);
        out.set_interaction(static_cast<cv1::Interaction>(sp->kind));
        out.set_command_sequence(sp->command_sequence);
        out.set_operator_id(sp->operator_id);
        out.set_waypoint_index(sp->waypoint_index);
        out.set_waypoint_count(sp->waypoint_count);
        if (!stream->Write(out)) break;
      }
    }
    links_.fetch_sub(1);
    log_->info("drone link closed: drone={}", id);
    return grpc::Status::OK;
  }

  grpc::Status PickAndPlace(grpc::ServerContext* ctx, const cv1::PickAndPlaceRequest* req,
                            cv1::InteractionReply* out) override {
    auto who = Authorize(*ctx, Rpc::kPickAndPlace);
    if (!who.ok()) return ToGrpc(who.status());
    auto r =
        core_->PickAndPlace(CommandOf(req->header(), *who), FromProto(req->eye()), FromProto(req->hand()),
                            FromProto(req->hand_displacement()), NowS());
    return Reply(r, out);
  }

  grpc::Status GazeToSee(grpc::ServerContext* ctx, const cv1::GazeToSeeRequest* req,
                         cv1::InteractionReply* out) override {
    auto who = Authorize(*ctx, Rpc::kGazeToSee);
    if (!who.ok()) return ToGrpc(who.status());
    auto r = core_->GazeToSee(CommandOf(req->header(), *who), FromProto(req->eye()),
                              FromProto(req->direction()), NowS());
    return Reply(r, out);
  }

  grpc::Status Joypad(grpc::ServerContext* ctx, const cv1::JoypadRequest* req,
                      cv1::InteractionReply* out) override {
    auto who = Authorize(*ctx, Rpc::kJoypad);
    if (!who.ok()) return ToGrpc(who.status());
    control::JoypadInput in{req->left_x(), req->left_y(), req->right_x(), req->right_y()};
    auto r = core_->Joypad(CommandOf(req->header(), *who), in, req->dt_s(), NowS());
    return Reply(r, out);
  }

  grpc::Status GoToView(grpc::ServerContext* ctx, const cv1::GoToViewRequest* req,
                        cv1::InteractionReply* out) override {
    auto who = Authorize(*ctx, Rpc::kGoToView);
    if (!who.ok()) return ToGrpc(who.status());
    auto r = core_->GoToView(CommandOf(req->header(), *who), req->view_id(), NowS());
    return Reply(r, out);
  }

  grpc::Status Explore(grpc::ServerContext* ctx, const cv1::ExploreRequest* req,
                       cv1::InteractionReply* out) override {
    auto who = Authorize(*ctx, Rpc::kExplore);
    if (!who.ok()) return ToGrpc(who.status());
    auto r = core_->Explore(CommandOf(req->header(), *who), req->start(), NowS());
    return Reply(r, out);
  }

  grpc::Status GetControlState(grpc::ServerContext* ctx, const cv1::ControlStateRequest* req,
                               cv1::ControlState* out) override {
    if (auto who = Authorize(*ctx, Rpc::kGetControlState); !who.ok()) return ToGrpc(who.status());
    const control::DroneView v = core_->View(req->drone_id().empty() ? "drone" : req->drone_id());
    out->set_drone_known(v.known);
    auto* d = out->mutable_drone();
    d->set_drone_id(req->drone_id().empty() ? "drone" : req->drone_id());
    d->set_timestamp_s(v.state.timestamp_s);
    ToProto(v.state.position, d->mutable_position());
    ToProto(v.state.velocity, d->mutable_velocity());
    d->set_yaw(v.state.yaw);
    d->set_camera_pitch(v.state.camera_pitch);
    out->set_command_sequence(v.command_sequence);
    out->set_interaction(static_cast<cv1::Interaction>(v.kind));
    out->set_operator_id(v.operator_id);
    ToProto(v.target.position, out->mutable_target());
    out->set_target_yaw(v.target.yaw);
    out->set_target_camera_pitch(v.target.camera_pitch);
    for (const auto& w : v.waypoints) ToProto(w, out->add_waypoints());
    out->set_waypoint_index(v.waypoint_index);
    out->set_setpoint_sequence(v.setpoint_sequence);
    out->set_states_received(v.states);
    out->set_setpoints_sent(v.setpoints);
    out->set_free_cells(core_->CountCells(control::Occupancy::kFree));
    out->set_occupied_cells(core_->CountCells(control::Occupancy::kOccupied));
    out->set_using_regions(core_->UsingRegions());
    for (const auto& z : core_->options().safe.zones) {
      auto* oz = out->add_zones();
      oz->set_name(z.name);
      ToProto(z.min, oz->mutable_min());
      ToProto(z.max, oz->mutable_max());
      if (z.vertical_axis >= 0) {  // a prism: its polygon, so viewers can draw it
        oz->set_prism_axis(static_cast<uint32_t>(z.vertical_axis + 1));
        for (const glm::dvec2& uv : z.polygon) {
          oz->add_polygon(uv.x);
          oz->add_polygon(uv.y);
        }
      }
    }
    ToProto(core_->frame().up, out->mutable_up());
    out->set_drone_links(static_cast<uint32_t>(links_.load()));
    out->set_exploring(v.exploring);
    out->set_explore_decisions(v.explore_decisions);
    out->set_explore_note(v.explore_note);
    const control::ExploreCoverage cov = core_->Coverage();
    out->set_explore_surface_cells(cov.surface_cells);
    out->set_explore_covered_cells(cov.covered_cells);
    return grpc::Status::OK;
  }

 private:
  grpc::Status Reply(const absl::StatusOr<control::CommandResult>& r, cv1::InteractionReply* out) {
    if (!r.ok()) return ToGrpc(r.status());
    FillReply(*r, out);
    return grpc::Status::OK;
  }

  absl::StatusOr<std::string> Authorize(const grpc::ServerContext& ctx, Rpc rpc) {
    if (!authorize_) return std::string();
    return authorize_(ctx, rpc);
  }

  control::ControlCore* core_;
  AuthorizeFn authorize_;
  std::atomic<int> links_{0};
  std::shared_ptr<spdlog::logger> log_ = log::Get("control");
};

// ---------------------------------------------------------------------------------------------

absl::StatusOr<std::unique_ptr<ControlServiceHost>> ControlServiceHost::Start(
    const ControlServiceOptions& options, ModelStore* store, AuthorizeFn authorize,
    std::shared_ptr<ObservedChunks> observed) {
  std::unique_ptr<ControlServiceHost> h(new ControlServiceHost());
  h->observed_ = std::move(observed);
  EXO_ASSIGN_OR_RETURN(h->core_, control::ControlCore::Create(options.core));
  h->impl_ = std::make_unique<Impl>(h->core_.get(), std::move(authorize));
  h->store_ = store;
  h->feeder_ = std::thread([p = h.get()] { p->Feed(); });
  // Autonomous exploration: a few decisions' checks a second, off the wire threads.
  h->explorer_ = std::thread([p = h.get()] {
    while (!p->stop_.load()) {
      for (const std::string& id : p->core_->ExploringDrones()) p->core_->ExploreStep(id, NowS());
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  });
  return h;
}

ControlServiceHost::~ControlServiceHost() { Stop(); }

grpc::Service* ControlServiceHost::service() { return impl_.get(); }

void ControlServiceHost::Stop() {
  stop_.store(true);
  if (feeder_.joinable()) feeder_.join();
  if (explorer_.joinable()) explorer_.join();
}

void ControlServiceHost::Feed() {
  auto log = log::Get("control");
  auto sub = store_->Subscribe(0, 0);
  // The chunks published labelled (observed_chunks.h): their published deltas are skipped.
  auto labelled = [this](uint64_t id) { return observed_ && observed_->Contains(id); };
  while (!stop_.load()) {
    if (observed_)
      for (auto& [id, mesh] : observed_->TakeChanged()) {
        if (mesh.empty()) core_->RemoveChunk(id);
        else core_->UpsertChunk(id, std::move(mesh));
      }
    for (const DeltaPtr& d : sub->Next(100)) {
      switch (d->kind_case()) {
        case v1::Delta::kSceneParams: {
          const auto& o = d->scene_params().origin_in_world();
          core_->SetOrigin({o.x(), o.y(), o.z()});
          break;
        }
        case v1::Delta::kMeshChunkUpserted: {
          // Scene completion's meshes are hallucinated surface: not in the drone's map.
          if (IsCompletionChunk(d->mesh_chunk_upserted().chunk_id())) break;
          if (labelled(d->mesh_chunk_upserted().chunk_id())) break;  // the observed one instead
          auto mesh = MeshFromProto(d->mesh_chunk_upserted());
          if (mesh.ok()) core_->UpsertChunk(d->mesh_chunk_upserted().chunk_id(), *std::move(mesh));
          break;
        }
        case v1::Delta::kMeshChunkRemoved:
          if (labelled(d->mesh_chunk_removed().chunk_id())) break;
          core_->RemoveChunk(d->mesh_chunk_removed().chunk_id());
          break;
        case v1::Delta::kViewAdded: {
          const auto& v = d->view_added();
          // Hallucinated pixels are not the drone's: a DR keyframe's depth lies BEHIND the removed
          // object (carving it would make the object's inside free space), a completion's is a
          // guess.
          if (v.inpainted() || IsCompletionView(v.view_id())) break;
          auto pose = PoseFromProto(v.local_from_cam());
          auto cam = IntrinsicsFromProto(v.intrinsics());
          if (!pose.ok() || !cam.ok()) break;
          absl::StatusOr<ImageF> depth =
              v.has_depth() ? DepthFromProto(v.depth()) : absl::StatusOr<ImageF>(ImageF());
          // The sky rule's colour test needs the view's colour (decoded only for it).
          absl::StatusOr<ImageU8> colour = absl::NotFoundError("no colour");
          if (core_->options().carve_sky_rule && depth.ok() && !v.color_jpeg().empty())
            colour = DecodeJpeg(std::span(reinterpret_cast<const uint8_t*>(v.color_jpeg().data()),
                                          v.color_jpeg().size()));
          core_->AddView(v.view_id(), *pose, *cam, depth.ok() ? &*depth : nullptr,
                         colour.ok() ? &*colour : nullptr);
          break;
        }
        case v1::Delta::kViewUpdated: {
          auto pose = PoseFromProto(d->view_updated().local_from_cam());
          if (pose.ok()) core_->UpdateViewPose(d->view_updated().view_id(), *pose);
          break;
        }
        case v1::Delta::kViewRemoved:
          core_->RemoveView(d->view_removed().view_id());
          break;
        default:
          break;
      }
    }
  }
  sub->Close();
}

}  // namespace exo
