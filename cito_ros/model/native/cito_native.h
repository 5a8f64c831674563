// Native part of cito_ros: MuJoCo engine plugins and the per-step linearization.
#ifndef CITO_NATIVE_H_
#define CITO_NATIVE_H_

#include <stddef.h>

#include <mujoco/mujoco.h>

// Register cito.compensated_motor and cito.virtual_contact (call once per process).
void cito_register_plugins(void);

// Per-step outputs of cito_linearize beyond the matrices.
enum {
  CITO_FLAG_ONE_SIDED = 0,   // position columns taken as backward differences (contact switch ahead), or
                             // central ones where both sides agree but not with the nominal collision
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
// control at its limit is differenced inward. Each step starts from its own state: the nominal
// evaluation from a zero warmstart, then it and every perturbation from the nominal accelerations,
// so the result does not depend on nthread. The position and velocity columns (of A and C) of the
// dofs with skip_dofs[j] != 0 (nv entries) are not computed in the steps t < skip_steps and are
// zero there. Returns 0, or -1 on an unsupported model (error message written to error).
int cito_linearize(const mjModel* m, mjData** datas, int nthread, int T, const mjtNum* states,
                   const mjtNum* controls, mjtNum eps, const int* skip_dofs, int skip_steps, mjtNum* A,
                   mjtNum* B, mjtNum* C, mjtNum* D, int* flags, char* error, int error_size);

// The forward pass of iLQR: n_trials rollouts of n_knots knots of steps_per_knot steps each from
// initial_state (nstate, mjSTATE_FULLPHYSICS), whose decisions (width per knot) are chosen knot by
// knot from the state x_l the trial reached at the knot's start:
//   c_l = clip(decisions_l + alpha k_l + K_l (x_l - xref_l), lower_l, upper_l),  alpha = step_lengths[trial]
// (x_l - xref_l in the tangent space, nx = 2 nv; xref_l = knot_states[l]). Decision i drives
// actuator actuators[i] (-1: none); the other controls are zero. Row-major arrays:
// knot_states N x nstate, decisions/k/lower/upper N x width, K N x width x nx.
typedef struct {
  int n_trials, n_knots, steps_per_knot, width;
  const mjtNum *initial_state, *knot_states, *decisions, *k, *K, *step_lengths, *lower, *upper;
  const int* actuators;
  mjtNum* trials;      // out: n_trials x N x width, the decisions each trial chose
  mjtNum* states;      // out: n_trials x (N steps_per_knot) x nstate, the state after each step
  mjtNum* sensordata;  // out: n_trials x (N steps_per_knot) x nsensordata, the sensors before each step
  int* warnings;       // out: n_trials x mjNWARNING, the MuJoCo warnings raised
} CitoFeedback;

// Each trial is stepped as mujoco.rollout steps an open-loop rollout (inputs reset, zero initial
// warmstart, warnings cleared at the start; after a warning the remaining steps repeat the state
// reached), so the open-loop rollout of the chosen decisions reproduces it bit for bit. The trials
// run side by side on nthread threads, each using one of the caller's mjData (datas[nthread],
// overwritten). Returns 0, or -1 (error message written to error).
int cito_feedback_rollouts(const mjModel* m, mjData** datas, int nthread, const CitoFeedback* feedback,
                           char* error, int error_size);

// PD joint tracking (cito_ros.tracking): `steps` steps of d from initial_state (nstate,
// mjSTATE_FULLPHYSICS; d reset first, as a fresh mjData), where before step s the motor
// motor_ids[j] of joint j gets clamp(kp_j (q_ref[s, j] - q_j) + kd_j (qdot_ref[s, j] - qdot_j),
// -torque_limit_j, torque_limit_j), q_j = qpos[qpos_adr[j]], qdot_j = qvel[dof_adr[j]], plus
// feed_forward[s, j] inside the clamp where feed_forward is not NULL, and every other control is zero;
// where speed_limit is not NULL, those torques then pass the executor's speed guard (joint speeds kept within
// speed_limit speed_horizon seconds ahead, and u plus the arm's bias forces within the torque limits:
// cito_ros.model.speed_guard.within_speed_limits with the bias forces at each step's state).
// Row-major arrays; q_ref, qdot_ref, feed_forward: steps x n_joints; n_joints <= 64.
typedef struct {
  int steps, n_joints;
  const mjtNum *initial_state, *q_ref, *qdot_ref, *kp, *kd, *torque_limit;
  const mjtNum* feed_forward;  // NULL: none
  const mjtNum* speed_limit;   // NULL: no speed guard
  mjtNum speed_horizon;
  const int *qpos_adr, *dof_adr, *motor_ids;
  mjtNum* states;      // out: steps x nstate, the state after each step
  mjtNum* sensordata;  // out: steps x nsensordata, the sensors before each step
  mjtNum* controls;    // out: steps x nu, the controls of each step
  int* warnings;       // out: mjNWARNING, the MuJoCo warnings raised
} CitoTracking;
// Returns 0 (the caller checks the indices).
int cito_track(const mjModel* m, mjData* d, const CitoTracking* tracking);
// Runs run(job) for the njob jobs (an array of job_size-byte items), each on a thread of its own,
// the first on the calling thread. Returns 0, or -1 when out of memory (nothing ran).
int cito_run_threads(void* (*run)(void*), void* jobs, size_t job_size, int njob);

#endif  // CITO_NATIVE_H_
