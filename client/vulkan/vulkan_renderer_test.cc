#include "client/vulkan/vulkan_renderer.h"

#include <cmath>

#include <gtest/gtest.h>

namespace exo {
namespace {

VulkanRendererOptions ValidatedOptions() {
  VulkanRendererOptions o;
  o.enable_validation = true;
  return o;
}

TEST(VulkanRendererTest, CreatesOnLavapipeWithValidation) {
  auto r = VulkanRenderer::Create(ValidatedOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_NE((*r)->DeviceName().find("llvmpipe"), std::string::npos) << (*r)->DeviceName();
  EXPECT_TRUE((*r)->ValidationErrors().empty());
}

TEST(VulkanRendererTest, NoDeviceGivesClearError) {
  // Point the loader at an ICD file that does not exist: no driver, no device.
  const char* old_drv = std::getenv("VK_DRIVER_FILES");
  const char* old_icd = std::getenv("VK_ICD_FILENAMES");
  std::string saved_drv = old_drv ? old_drv : "", saved_icd = old_icd ? old_icd : "";
  setenv("VK_DRIVER_FILES", "/nonexistent/icd.json", 1);
  setenv("VK_ICD_FILENAMES", "/nonexistent/icd.json", 1);
  auto r = VulkanRenderer::Create(VulkanRendererOptions{});
  if (old_drv) setenv("VK_DRIVER_FILES", saved_drv.c_str(), 1); else unsetenv("VK_DRIVER_FILES");
  if (old_icd) setenv("VK_ICD_FILENAMES", saved_icd.c_str(), 1); else unsetenv("VK_ICD_FILENAMES");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), absl::StatusCode::kUnavailable) << r.status();
  EXPECT_NE(r.status().message().find("Vulkan"), std::string::npos) << r.status();
}

}  // namespace
}  // namespace exo
