// The three-phase MPC (flight_sw/guidance) as a guidance law behind the plug-in interface
// (flight_sw/include/rvd_guidance.h): the flight executable's default law.
#pragma once

#include "flight_sw/guidance/params.hpp"
#include "flight_sw/include/rvd_guidance.h"

namespace rvd::guidance {

class Guidance;

// The law's table. create() takes its parameters from config->native (a GuidanceParams*, what the
// flight executable's options made) when given, else the defaults of params.hpp with the vehicle,
// orbit, per-phase period, horizon and delta-v limit and the geometry of the generic configuration.
const rvd_guidance_law* mpc_law();

// The generic configuration that describes `p` (the harness fills it from its parameters, so that
// every law sees the same vehicle, periods and limits). `params`/`native` are left null.
rvd_guidance_config generic_config(const GuidanceParams& p);

// The guidance parameters a generic configuration describes: the defaults of params.hpp with its
// vehicle, orbit, per-phase period, horizon and delta-v limit and geometry (config.native, when given,
// instead). Margins are left at zero: nav::derive_margins() turns the configuration's error model into
// them as the flight executable does. For laws that reuse the MPC's QPs or switching rules.
GuidanceParams params_from_config(const rvd_guidance_config& config);

// The guidance inside a state mpc_law()->create made (for inspection: its last QPs and plans).
const Guidance* mpc_law_guidance(const void* law_state);

}  // namespace rvd::guidance
