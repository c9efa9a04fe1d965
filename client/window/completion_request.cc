#include "client/window/completion_request.h"

#include <chrono>
#include <cstdio>

#include "proto/exoview.grpc.pb.h"
#include "proto/frame_proto.h"

namespace exo {
namespace {

// "12 345": thousands separated by a thin space, as the HUD's other counts.
std::string Grouped(uint64_t n) {
  std::string s = std::to_string(n), out;
  for (size_t i = 0; i < s.size(); ++i) {
    if (i > 0 && (s.size() - i) % 3 == 0) out += ' ';
    out += s[i];
  }
  return out;
}

}  // namespace

CompletionRequester::CompletionRequester(std::shared_ptr<grpc::Channel> channel)
    : channel_(std::move(channel)) {}

CompletionRequester::~CompletionRequester() {
  if (thread_.joinable()) thread_.join();
}

CompletionRequester::State CompletionRequester::state() const {
  std::lock_guard lock(mu_);
  return state_;
}

bool CompletionRequester::Request(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                  uint32_t max_side_px) {
  {
    std::lock_guard lock(mu_);
    if (state_.busy) {
      state_.line = "completion: still waiting for the previous request";
      return false;
    }
    state_.busy = true;
    ++state_.requests;
    state_.line = "completion: asking the server ...";
  }
  if (thread_.joinable()) thread_.join();
  v1::CompleteViewRequest req;
  IntrinsicsToProto(camera, req.mutable_camera());
  PoseToProto(local_from_cam, req.mutable_local_from_cam());
  req.set_max_side_px(max_side_px);
  thread_ = std::thread([this, req] {
    auto stub = v1::Exoview::NewStub(channel_);
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    v1::CompleteViewReply r;
    const auto t0 = std::chrono::steady_clock::now();
    const grpc::Status st = stub->CompleteView(&ctx, req, &r);
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    char b[320];
    State s;
    if (!st.ok()) {
      std::snprintf(b, sizeof(b), "completion failed: %s", st.error_message().c_str());
      s.ok = false;
    } else if (r.outcome() == v1::CompleteViewReply::NOTHING_TO_COMPLETE) {
      std::snprintf(b, sizeof(b), "nothing to complete (%s hole px of %ux%u)",
                    Grouped(r.hole_px()).c_str(), r.width(), r.height());
    } else {
      std::snprintf(b, sizeof(b),
                    "completed %s px, view 0x%08x (%s surface, %s void; %ux%u, %.0f ms on the "
                    "server, %.0f ms round trip)",
                    Grouped(r.hole_px()).c_str(), r.view_id(), Grouped(r.surface_hole_px()).c_str(),
                    Grouped(r.void_hole_px()).c_str(), r.width(), r.height(), r.total_ms(), ms);
      s.view_id = r.view_id();
      s.hole_px = r.hole_px();
    }
    std::lock_guard lock(mu_);
    s.busy = false;
    s.requests = state_.requests;
    s.replies = state_.replies + 1;
    if (s.view_id == 0 && s.ok) s.view_id = state_.view_id;
    s.line = b;
    state_ = s;
  });
  return true;
}

}  // namespace exo
