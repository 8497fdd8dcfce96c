// Elementary functions with the same bits on every x86-64 machine.
//
// glibc picks its exp, expm1, sin and cos at load time by the processor
// (GNU indirect functions): a machine with FMA runs __exp_fma, one without
// __exp_sse2 or __exp_avx, and the two differ in the last bit for about 1 in
// 1,500 arguments (2e6 uniform arguments each, this machine, glibc 2.36, with
// GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA,-AVX512F,-AVX,-FMA4 as the
// machine without: exp 1,350, expm1 859, sin 1,428, cos 1,363 differ, by one
// unit each). The engine's promise that a seed gives the same bits on any
// machine of a cluster (docs/distributed.md, "Any instruction set") would then
// hold only between machines of one kind. These are SLEEF's deterministic pure C
// versions instead (libsleef 3.5, Debian's libsleef-dev: "cinz_..._u10purec",
// an error bound of 1.0 ulp, no FMA, no dispatch by processor), one compiled
// code path for every x86-64 processor. tests/cpp/test_det_math.cpp
// holds them to their bound against long double references;
// tests/python/test_isa_bits.py compares whole runs across builds and libm
// variants. (The engine's hot paths need none of them: the free path's
// logarithm is fast_log.h's, the scattering azimuth phase.h's table.)
// The package computes some scene inputs in Python (an endoscope's pose from
// beta, media's power laws, generated meshes, the endoscope view's camera
// request) with sin, cos, tan, atan, exp, log and pow: it calls these through
// endophoton._core.det_* (endophoton.det), for the same reason
// (tests/python/test_det_inputs.py).
#pragma once

namespace ep {

double det_exp(double x);
double det_expm1(double x);
// sin x and cos x, together.
void det_sincos(double x, double* s, double* c);
double det_cos(double x);
double det_sin(double x);
// Natural logarithm; NaN below 0, -inf at 0.
double det_log(double x);
// x to the power y, with C99's special cases (pow(x, 0) = 1, pow(1, y) = 1, ...).
double det_pow(double x, double y);
// tan x (x in radians): the camera's half field of view on the plane at depth 1.
double det_tan(double x);
// atan x in (-pi/2, pi/2): the pixels' solid angles.
double det_atan(double x);

}  // namespace ep
