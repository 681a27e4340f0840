// Python binding of the flight application's per-message logic (flight_sw/app): a FlightApp built
// from the flight executable's own options, fed encoded nav messages, answering encoded cmd
// messages, without a link. The in-process path of the studies (rvd_pil/studies/inprocess.py) serves it
// from the host simulator, so it flies what the executable flies, message for message.
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <optional>
#include <string>
#include <vector>

#include "flight_sw/app/flight_app.hpp"
#include "flight_sw/link/messages.hpp"

namespace py = pybind11;
using rvd::app::FlightApp;
namespace msg = rvd::msg;

namespace rvd::app {
AppConfig parse_options(const std::vector<std::string>& args);  // main.cpp
}

namespace {

template <class M>
py::bytes encoded(const M& m) {
  uint8_t buf[M::kSize];
  msg::Error e = msg::Error::None;
  const size_t n = msg::encode(m, buf, sizeof buf, &e);
  if (n == 0) throw py::value_error(std::string("cannot encode: ") + msg::to_string(e));
  return py::bytes(reinterpret_cast<const char*>(buf), n);
}

}  // namespace

void bind_app(py::module_& m) {
  py::class_<FlightApp>(m, "FlightApp",
                        "The flight application without its link: FlightApp(options) takes the flight "
                        "executable's command-line options (e.g. ['--run', 'r1', '--horizon', '45,15,12']).")
      .def(py::init([](const std::vector<std::string>& args) {
             try {
               return new FlightApp(rvd::app::parse_options(args));
             } catch (const std::invalid_argument& e) {
               throw py::value_error(e.what());
             }
           }),
           py::arg("options"))
      .def(
          "handle_nav",
          [](FlightApp& app, const py::bytes& nav) -> py::object {
            const std::string data = nav;
            msg::Nav n;
            const msg::Error e = msg::decode(reinterpret_cast<const uint8_t*>(data.data()), data.size(), n);
            if (e != msg::Error::None) throw py::value_error(std::string("nav: ") + msg::to_string(e));
            std::optional<msg::Cmd> cmd;
            {
              py::gil_scoped_release release;
              cmd = app.handle_nav(n);
            }
            if (!cmd) return py::none();
            return encoded(*cmd);
          },
          py::arg("nav"), "one encoded nav -> the encoded cmd (None for a nav older than the last answered)")
      .def(
          "apply_config",
          [](FlightApp& app, const py::bytes& config) {
            const std::string data = config;
            msg::Config c;
            const msg::Error e = msg::decode(reinterpret_cast<const uint8_t*>(data.data()), data.size(), c);
            if (e != msg::Error::None) throw py::value_error(std::string("config: ") + msg::to_string(e));
            return encoded(app.apply_config(c));
          },
          py::arg("config"), "one encoded config (vehicle and settings) -> the encoded echo")
      .def(
          "handle_obstacles",
          [](FlightApp& app, const py::bytes& obstacles) {
            const std::string data = obstacles;
            msg::Obstacles m;
            const msg::Error e = msg::decode(reinterpret_cast<const uint8_t*>(data.data()), data.size(), m);
            if (e != msg::Error::None) throw py::value_error(std::string("obstacles: ") + msg::to_string(e));
            app.accept_obstacles(m);
          },
          py::arg("obstacles"), "one encoded obstacles message, kept for the next nav")
      .def(
          "take_obstacle_status",
          [](FlightApp& app) -> py::object {
            if (!app.take_obstacle_status_due()) return py::none();
            return encoded(app.obstacle_status());
          },
          "the encoded obstacle_status the last step owes before its cmd, else None")
      .def(
          "handle_chaser_attitude",
          [](FlightApp& app, const py::bytes& attitude) {
            const std::string data = attitude;
            msg::ChaserAttitude m;
            const msg::Error e = msg::decode(reinterpret_cast<const uint8_t*>(data.data()), data.size(), m);
            if (e != msg::Error::None) throw py::value_error(std::string("chaser_attitude: ") + msg::to_string(e));
            app.accept_chaser_attitude(m);
          },
          py::arg("chaser_attitude"), "one encoded chaser_attitude message, kept for the next nav")
      .def(
          "torque_for",
          [](const FlightApp& app, uint32_t step) -> py::object {
            const auto tq = app.torque_for(step);
            if (!tq) return py::none();
            return encoded(*tq);
          },
          py::arg("step"), "the encoded torque message of that step (before its cmd), else None")
      .def("hello", [](const FlightApp& app, uint32_t session) { return encoded(app.hello(session)); },
           py::arg("session") = 1, "the encoded hello message")
      .def_property_readonly(
          "guidance", [](const FlightApp& app) { return app.built_in_guidance(); }, py::return_value_policy::reference_internal,
          "the built-in MPC's Guidance (last_qp, last_solution_u), None when a plug-in law flies")
      .def("telemetry", [](const FlightApp& app) { return encoded(app.telemetry()); },
           "the encoded telemetry message (per-phase solve-time log)");
}
