// The pybind11 module `rvd_pil.flight_sw`: the same C++ core the flight executable runs, exposed to Python
// so that tests run natively and fast. Each part binds itself in its own file.
#include <pybind11/pybind11.h>

namespace py = pybind11;

void bind_solver(py::module_& m);    // bind_solver.cpp
void bind_guidance(py::module_& m);  // bind_guidance.cpp
void bind_link(py::module_& m);      // bind_link.cpp
void bind_nav(py::module_& m);       // bind_nav.cpp
void bind_app(py::module_& m);       // bind_app.cpp

PYBIND11_MODULE(flight_sw, m) {
  m.doc() = "rvd-pil flight software core: Fast MPC solver, three-phase RVD guidance, link codec, navigation filter";
  bind_solver(m);
  bind_guidance(m);
  bind_link(m);
  bind_nav(m);
  bind_app(m);
}
