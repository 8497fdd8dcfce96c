// Binding of native/det_math.h's elementary functions for the package's own
// scene inputs (endophoton.det): sin, cos, tan, atan, exp, log and pow with the same bits
// on every x86-64 machine, where math.* and numpy's float64 loops are picked by
// the processor. Each takes a float64 array of any shape (a scalar is a 0-d
// array) and returns a new one of that shape, element by element in C++, so a
// mesh's thousands of angles cost one call.
#include "det_math.h"

#include <stdexcept>
#include <vector>

#include "common.h"

namespace ep::bind {

namespace {

using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

std::vector<py::ssize_t> shape_of(const DoubleArray& a) {
    return std::vector<py::ssize_t>(a.shape(), a.shape() + a.ndim());
}

template <double (*F)(double)>
py::array_t<double> unary(const DoubleArray& x) {
    py::array_t<double> out(shape_of(x));
    const double* in = x.data();
    double* o = out.mutable_data();
    for (py::ssize_t i = 0; i < x.size(); ++i) o[i] = F(in[i]);
    return out;
}

py::array_t<double> power(const DoubleArray& x, const DoubleArray& y) {
    if (shape_of(x) != shape_of(y))
        throw std::invalid_argument("det_pow: x and y must have the same shape (broadcast them first)");
    py::array_t<double> out(shape_of(x));
    const double* a = x.data();
    const double* b = y.data();
    double* o = out.mutable_data();
    for (py::ssize_t i = 0; i < x.size(); ++i) o[i] = det_pow(a[i], b[i]);
    return out;
}

}  // namespace

void bind_det_math(py::module_& m) {
    m.def("det_sin", &unary<det_sin>, py::arg("x"),
          "sin x (x in radians), elementwise; SLEEF, 1 ulp, the same bits on every x86-64");
    m.def("det_cos", &unary<det_cos>, py::arg("x"),
          "cos x (x in radians), elementwise; SLEEF, 1 ulp, the same bits on every x86-64");
    m.def("det_tan", &unary<det_tan>, py::arg("x"),
          "tan x (x in radians), elementwise; SLEEF, 1 ulp, the same bits on every x86-64");
    m.def("det_atan", &unary<det_atan>, py::arg("x"),
          "atan x (radians, in (-pi/2, pi/2)), elementwise; SLEEF, 1 ulp, the same bits on every x86-64");
    m.def("det_exp", &unary<det_exp>, py::arg("x"), "e^x, elementwise; SLEEF, 1 ulp, the same bits on every x86-64");
    m.def("det_log", &unary<det_log>, py::arg("x"), "ln x, elementwise; SLEEF, 1 ulp, the same bits on every x86-64");
    m.def("det_pow", &power, py::arg("x"), py::arg("y"),
          "x ** y, elementwise over two arrays of one shape; SLEEF, 1 ulp, the same bits on every x86-64");
}

}  // namespace ep::bind
