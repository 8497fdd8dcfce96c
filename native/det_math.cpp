#include "det_math.h"

#include <sleef.h>

namespace ep {

double det_exp(double x) { return Sleef_cinz_expd1_u10purec(x); }

double det_expm1(double x) { return Sleef_cinz_expm1d1_u10purec(x); }

void det_sincos(double x, double* s, double* c) {
    const Sleef_double_2 r = Sleef_cinz_sincosd1_u10purec(x);
    *s = r.x;
    *c = r.y;
}

double det_cos(double x) { return Sleef_cinz_cosd1_u10purec(x); }

double det_sin(double x) { return Sleef_cinz_sind1_u10purec(x); }

double det_log(double x) { return Sleef_cinz_logd1_u10purec(x); }

double det_pow(double x, double y) { return Sleef_cinz_powd1_u10purec(x, y); }

double det_tan(double x) { return Sleef_cinz_tand1_u10purec(x); }

double det_atan(double x) { return Sleef_cinz_atand1_u10purec(x); }

}  // namespace ep
