"""host_sim: the truth simulator of rvd-pil.

Relative motion of a chaser about a target on a circular LEO orbit, in the target's LVLH frame
(x radial out / R-bar, y along-track / V-bar, z orbit normal). SI units throughout: metres,
seconds, kilograms, newtons, radians.
"""

__version__ = "0.1.0"
