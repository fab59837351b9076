/* The certificate's check of one plan (tspend/controllers/mpsc.py, Rollout.check), appended
   to the CasADi source of the rollouts (one function per model) and compiled with it.

   The plan on the RK4 steps is made once (`prepare`), then the models' rollouts run in
   `order`, each (the first too, once its guard is measured) started only when `guard_ns`
   still fits before `deadline_ns` (both on
   CLOCK_MONOTONIC, Python's time.perf_counter), stopping at the first model whose excess
   is positive (it moves to the front of `order`: the model that broke a bound last is
   tried first next time).  One call from Python for the whole check: a Python call per
   model cost 3-4 us each, a tenth of a model's rollout. */

#include <time.h>

/* a guard this long or longer is unmeasured (mpsc.py's _FAR_NS) */
#define TSPEND_UNMEASURED_NS (1LL << 62)

typedef int (*tspend_casadi_fn)(const casadi_real **arg, casadi_real **res, casadi_int *iw,
                                casadi_real *w, int mem);

static long long tspend_check_ns(clockid_t clock) {
  struct timespec t;
  clock_gettime(clock, &t);
  return (long long)t.tv_sec * 1000000000LL + t.tv_nsec;
}

/* Returns the models run; *status: 0 every model kept its bounds by its excess, 1 one did
   not, 2 stopped before the next model at the deadline, 3 a function failed; *cpu_s: this
   thread's CPU time over the models. */
CASADI_SYMBOL_EXPORT int tspend_mpsc_check(
    void *prepare, const casadi_real **prepare_arg, casadi_real **prepare_res, int models,
    void **fns, const casadi_real **arg, casadi_real ***res, casadi_int *iw, casadi_real *w,
    const casadi_real *excess, int *order, long long deadline_ns, long long guard_ns,
    int *status, double *cpu_s) {
  int n = 0;
  *status = 0;
  *cpu_s = 0.0;
  if (((tspend_casadi_fn)prepare)(prepare_arg, prepare_res, iw, w, 0)) {
    *status = 3;
    return 0;
  }
  long long cpu0 = tspend_check_ns(CLOCK_THREAD_CPUTIME_ID);
  for (; n < models; ++n) {
    int m = order[n];
    /* the first model too, unless its guard is unmeasured (a first probe runs one) */
    if ((n || guard_ns < TSPEND_UNMEASURED_NS) &&
        tspend_check_ns(CLOCK_MONOTONIC) + guard_ns > deadline_ns) {
      *status = 2;
      break;
    }
    if (((tspend_casadi_fn)fns[m])(arg, res[m], iw, w, 0)) {
      *status = 3;
      ++n;
      break;
    }
    if (excess[m] > 0.0) {
      for (int i = n; i > 0; --i) order[i] = order[i - 1];
      order[0] = m;
      *status = 1;
      ++n;
      break;
    }
  }
  *cpu_s = 1e-9 * (double)(tspend_check_ns(CLOCK_THREAD_CPUTIME_ID) - cpu0);
  return n;
}
