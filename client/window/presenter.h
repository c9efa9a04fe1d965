// On-screen presentation of the viewer (issue 17): an SDL2 window (X11 or Wayland) with its own
// Vulkan instance, device and swapchain, and the Dear ImGui overlay (Debian libimgui-dev's SDL2 +
// Vulkan backends). Each frame the renderer's read-back RGB8 image (any size: the adaptive
// resolution renders ½ or ¼ of the window while moving) is copied into a host-visible staging
// image, blitted with linear filtering to the swapchain image (scaling + RGBA -> BGRA in one
// command), the ImGui draw data is drawn on top (load, not clear) and the image is presented.
// vulkan.h and SDL.h never appear in this header (pimpl); the caller drives ImGui itself.
#pragma once

#include <functional>
#include <memory>
#include <string>

#include "common/image.h"
#include "common/status.h"

union SDL_Event;

namespace exo {

struct PresenterOptions {
  int width = 1280, height = 720;
  std::string title = "Exoview";
  bool vsync = false;  // FIFO present mode; off = MAILBOX/IMMEDIATE where available
  absl::Status Validate() const;
};

struct PresentTimings {
  double upload_ms = 0;  // RGB8 -> mapped staging buffer (host copy)
  double submit_ms = 0;  // acquire + record + submit + wait (blit + overlay draw) + present
};

class Presenter {
 public:
  // Opens the window (SDL_VIDEODRIVER picks X11/Wayland) and the swapchain. kUnavailable with a
  // clear message when there is no display or no Vulkan device that can present to it.
  static absl::StatusOr<std::unique_ptr<Presenter>> Create(const PresenterOptions& options);
  ~Presenter();
  Presenter(const Presenter&) = delete;
  Presenter& operator=(const Presenter&) = delete;

  // Forwards an SDL event to ImGui; true when ImGui wants it (e.g. the mouse over a panel).
  bool ProcessEvent(const SDL_Event& event);
  // Starts an ImGui frame (backends + ImGui::NewFrame); call before any ImGui widget.
  void NewFrame();
  // Ends the ImGui frame and presents: `frame` (RGB8, sRGB) when non-null is uploaded first;
  // null re-presents the last uploaded frame (nothing changed in the scene) with a fresh overlay.
  absl::Status Present(const ImageU8* frame, PresentTimings* timings = nullptr);

  // Current drawable size (pixels).
  int width() const;
  int height() const;
  std::string DeviceName() const;

  class Impl;

 private:
  explicit Presenter(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace exo
