"""host_sim: the truth simulator of rvd-pil.

Relative motion of a chaser about a target on a circular LEO orbit, in the target's LVLH frame
(x radial out / R-bar, y along-track / V-bar, z orbit normal). SI units throughout: metres,
seconds, kilograms, newtons, radians (degrees only where a name says _deg).

Modules: `simulator` (Simulator: truth, thrusters, sensors, one control period at a time),
`scenario` (TOML scenarios in rvd_pil/host_sim/scenarios/, random Monte Carlo states), `record` (crash-safe
run records), and the models underneath: `cw`, `dynamics`, `atmosphere`, `frames`, `attitude`,
`thrusters`, `noise`, `constants`.
"""

__version__ = "0.1.0"
