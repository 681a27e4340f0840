"""The guidance parameters the flight executable runs with, for in-process references."""
from rvd_pil import flight_sw


def flight_params() -> "flight_sw.GuidanceParams":
    """Defaults plus the margins the executable derives (--margins auto) for a noise-free error model,
    as in an ideal run (CW truth, no noise, impulsive burns)."""
    params = flight_sw.GuidanceParams()
    params.margins = flight_sw.derive_margins(flight_sw.ErrorModel(), params)
    return params
