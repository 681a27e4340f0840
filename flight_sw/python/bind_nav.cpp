// Python binding of the onboard navigation filter (flight_sw/nav), so tests can drive it with the
// host simulator's truth and sensors.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <stdexcept>
#include <string>

#include "flight_sw/nav/margins.hpp"
#include "flight_sw/nav/nav_filter.hpp"

namespace py = pybind11;
using namespace rvd::nav;

void bind_nav(py::module_& m) {
  py::enum_<NavUpdate>(m, "NavUpdate")
      .value("initialised", NavUpdate::Initialised)
      .value("fused", NavUpdate::Fused)
      .value("gated", NavUpdate::Gated)
      .value("reinitialised", NavUpdate::Reinitialised)
      .value("passthrough", NavUpdate::Passthrough)
      .value("invalid", NavUpdate::Invalid);
  py::class_<NavFilterParams>(m, "NavFilterParams")
      .def(py::init<>())
      .def_readwrite("enabled", &NavFilterParams::enabled)
      .def_readwrite("sigma_position_m", &NavFilterParams::sigma_position_m)
      .def_readwrite("sigma_velocity_mps", &NavFilterParams::sigma_velocity_mps)
      .def_readwrite("thrust_error_sigma", &NavFilterParams::thrust_error_sigma)
      .def_readwrite("thrust_error_tau_s", &NavFilterParams::thrust_error_tau_s)
      .def_readwrite("finite_burns", &NavFilterParams::finite_burns)
      .def_readwrite("accel_noise_mps2_rthz", &NavFilterParams::accel_noise_mps2_rthz)
      .def_readwrite("gate_chi2", &NavFilterParams::gate_chi2)
      .def_readwrite("max_rejections", &NavFilterParams::max_rejections);
  py::class_<ErrorModel>(m, "ErrorModel", "The disturbances the flight software is configured for.")
      .def(py::init<>())
      .def_readwrite("sigma_position_m", &ErrorModel::sigma_position_m)
      .def_readwrite("sigma_velocity_mps", &ErrorModel::sigma_velocity_mps)
      .def_readwrite("thrust_error_sigma", &ErrorModel::thrust_error_sigma)
      .def_readwrite("finite_burns", &ErrorModel::finite_burns)
      .def_readwrite("sigmas", &ErrorModel::sigmas);
  m.def("derive_margins", &derive_margins, py::arg("errors"), py::arg("params"),
        "Margins covering the error model (as the flight executable's --margins auto)");
  py::class_<NavFilter>(m, "NavFilter")
      .def(py::init([](const NavFilterParams& p, double n) {
             if (const char* err = p.validate(); *err) throw py::value_error(err);
             return NavFilter(p, n);
           }),
           py::arg("params"), py::arg("mean_motion_rad_s"))
      .def("reset", &NavFilter::reset)
      .def("command", &NavFilter::command, py::arg("t_s"), py::arg("dv_lvlh_mps"), py::arg("pulse_s"))
      .def(
          "update",
          [](NavFilter& f, double t_s, const rvd::guidance::Vector6d& z) {
            const NavEstimate& e = f.update(t_s, z);
            return py::make_tuple(rvd::guidance::Vector6d(e.x), rvd::guidance::Matrix6d(e.P), e.update, e.innovation_chi2,
                                  rvd::guidance::Vector6d(e.thrust_error), e.thrust_error_sigma);
          },
          py::arg("t_s"), py::arg("z"),
          "(x, P, update, innovation_chi2, thrust_error, thrust_error_sigma) after fusing z taken at t_s")
      .def_property_readonly("gated", &NavFilter::gated)
      .def_property_readonly("reinitialisations", &NavFilter::reinitialisations);
}
