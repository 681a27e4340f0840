// What the flight executable says about itself in hello: instruction set, tuned CPU, compiler, flags.
#pragma once

#include <string>

namespace rvd::app::build_info {

#if defined(__aarch64__)
inline constexpr const char* kArch = "aarch64";
#elif defined(__arm__)
inline constexpr const char* kArch = "armv7l";
#elif defined(__x86_64__)
inline constexpr const char* kArch = "x86_64";
#else
inline constexpr const char* kArch = "unknown";
#endif

#ifdef RVD_CPU_MODEL
inline constexpr const char* kCpuModel = RVD_CPU_MODEL;  // the -mcpu of a cross build
#else
inline constexpr const char* kCpuModel = "host";
#endif

#ifdef RVD_BUILD_FLAGS
inline constexpr const char* kBuildFlags = RVD_BUILD_FLAGS;
#else
inline constexpr const char* kBuildFlags = "";
#endif

inline std::string compiler() {
#if defined(__clang__)
  return std::string("clang ") + __clang_version__;
#elif defined(__GNUC__)
  return std::string("gcc ") + __VERSION__;
#else
  return "unknown";
#endif
}

}  // namespace rvd::app::build_info
