// The default flight executable's law: the three-phase MPC.
#include "flight_sw/guidance/plugin/mpc_law.hpp"

extern "C" const rvd_guidance_law* rvd_guidance_law_entry(void) { return rvd::guidance::mpc_law(); }
