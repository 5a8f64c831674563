// Native part of cito_ros: MuJoCo engine plugins and the per-step linearization.
#ifndef CITO_NATIVE_H_
#define CITO_NATIVE_H_

#include <mujoco/mujoco.h>

// Register cito.compensated_motor and cito.virtual_contact (call once per process).
void cito_register_plugins(void);

// Per-step outputs of cito_linearize beyond the matrices.
enum {
  CITO_FLAG_ONE_SIDED = 0,   // position columns taken as backward differences (contact switch ahead)
  CITO_FLAG_UNRESOLVED = 1,  // position columns where both sides switch contacts (central difference)
  CITO_FLAG_WARNINGS = 2,    // MuJoCo warnings raised while evaluating the step
  CITO_NFLAG = 3
};

// Finite-difference linearization of T simulation steps, in parallel on nthread threads, each
// using one of the caller's mjData of model m (datas[nthread], overwritten):
//   x_next = f(x, u),  A = df/dx (nx x nx),  B = df/du (nx x nu),    nx = 2 nv (tangent space)
//   s      = h(x, u),  C = dh/dx (ns x nx),  D = dh/du (ns x nu),    s = sensordata at x
// states: T x nstate (mjSTATE_FULLPHYSICS), controls: T x nu; outputs row-major per step.
// Forward differences of size eps, skipping unchanged pipeline stages as mjd_transitionFD does;
// a position perturbation that changes the set of contacts is retried on the other side; a
// control at its limit is differenced inward. Each step starts from its own state with a zero
// warmstart, so the result does not depend on nthread. Returns 0, or -1 on an unsupported model
// (error message written to error).
int cito_linearize(const mjModel* m, mjData** datas, int nthread, int T, const mjtNum* states,
                   const mjtNum* controls, mjtNum eps, mjtNum* A, mjtNum* B, mjtNum* C, mjtNum* D,
                   int* flags, char* error, int error_size);

#endif  // CITO_NATIVE_H_
