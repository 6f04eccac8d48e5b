/* The arithmetic helpers of the compiled one-state step (rddl/sim/cstep.py).

   The translator writes an instance's step as C over doubles; where Python's
   operators and the scalar step's helpers (`scalar._HELPERS`) differ from C's,
   these keep Python's result: a division by zero gives inf or nan (Python
   raises; numpy gives the same), `//` and `%` are Python's floor division and
   modulo, `_discrete` takes the first case whose cumulative probability passes
   the draw. Every helper is `static inline`: an instance that does not use one
   compiles without a warning under -Wall -Wextra. */
#include <math.h>
#include <stdint.h>
#include <string.h>
#include <stdlib.h>
static inline double py_div(double x, double y) {
    if (y == 0) { if (x == 0 || x != x) return NAN; return copysign(INFINITY, x) * copysign(1.0, y); }
    return x / y;
}
static inline double py_ln(double x) { return x > 0 ? log(x) : (x == 0 ? -INFINITY : NAN); }
static inline double py_sqrt(double x) { return x >= 0 ? sqrt(x) : NAN; }
static inline double py_pow(double x, double y) { return pow(x, y); }
static inline double py_sgn(double x) { return (double)((x > 0) - (x < 0)); }
/* Python's float // (its divmod: 1.0 // 0.1 is 9.0, not floor(10.000000000000002)) */
static inline double py_floordiv(double x, double y) {
    if (y == 0) return floor(py_div(x, y));
    double mod = fmod(x, y), div = (x - mod) / y;
    if (mod != 0 && ((y < 0) != (mod < 0))) div -= 1.0;
    if (div == 0) return copysign(0.0, x / y);
    double fl = floor(div);
    if (div - fl > 0.5) fl += 1.0;
    return fl;
}
static inline double py_mod(double x, double y) { double m = fmod(x, y); if (m != 0 && ((m < 0) != (y < 0))) m += y; return m; }
static inline double py_discrete(double u, const double *p, int n) {
    double acc = 0.0;
    for (int i = 0; i < n; i++) { acc += p[i]; if (u < acc) return (double)i; }
    return (double)(n - 1);
}
