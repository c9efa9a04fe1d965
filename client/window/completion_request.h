// Scene completion from the viewer (issue 18 item 4): key C in the window and in the browser page
// asks the server (CompleteView) to complete what the current camera sees where no stored view
// observed anything. The call runs on its own thread (one at a time: a press while one is in
// flight is ignored and says so); HudLine() is the HUD's line for the last reply. The completion
// view itself arrives through the model's deltas like every view (the overlay marks it).
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include <grpcpp/grpcpp.h>

#include "common/camera.h"
#include "common/rigid3.h"

namespace exo {

class CompletionRequester {
 public:
  explicit CompletionRequester(std::shared_ptr<grpc::Channel> channel);
  ~CompletionRequester();
  CompletionRequester(const CompletionRequester&) = delete;
  CompletionRequester& operator=(const CompletionRequester&) = delete;

  // Asks for a completion at this camera (scene-local pose). False (and the HUD says so) while
  // one is in flight.
  bool Request(const PinholeCamera& camera, const Rigid3d& local_from_cam,
               uint32_t max_side_px = 0);
  struct State {
    bool busy = false;
    bool ok = true;      // false: the last call failed
    uint64_t requests = 0, replies = 0;
    uint32_t view_id = 0;  // of the last completion (0: none)
    uint32_t hole_px = 0;
    std::string line;    // the HUD line ("" before the first press)
  };
  State state() const;
  std::string HudLine() const { return state().line; }

 private:
  std::shared_ptr<grpc::Channel> channel_;
  mutable std::mutex mu_;
  State state_;
  std::thread thread_;
};

}  // namespace exo
