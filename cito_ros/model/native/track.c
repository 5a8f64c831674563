// PD joint tracking, the robot's joint trajectory controller of cito_ros.tracking (see cito_native.h).
#include "cito_native.h"

// The executor's speed guard (cito_ros.model.speed_guard.within_speed_limits): u changed only where it would take a
// joint moving at qdot past speed_limit within speed_horizon, and kept within the motors' limits, with the bias
// forces the model's motors add on top too (u + bias within +-torque_limit, as a robot's motors bound the total the
// executor sends), at the arm's inertia and bias forces of this step's state (d->qM, d->qfrc_bias: forwarded by the
// caller, as the executor forwards them at every measured state); the Python oracle's operations in its order.
static void speed_guard(const mjModel* m, mjData* d, const CitoTracking* t, mjtNum* u) {
  int n = t->n_joints, nv = m->nv;
  mj_markStack(d);
  mjtNum* full = mj_stackAllocNum(d, (size_t)nv * nv);
  mjtNum* inertia = mj_stackAllocNum(d, (size_t)n * n);
  mjtNum* factor = mj_stackAllocNum(d, (size_t)n * n);
  mjtNum* work = mj_stackAllocNum(d, 8 * (size_t)n);
  mjtNum *acceleration = work, *low = work + n, *high = work + 2 * n, *clipped = work + 3 * n;
  mjtNum *rest = work + 4 * n, *step = work + 5 * n, *low_Nm = work + 6 * n, *high_Nm = work + 7 * n;
  for (int j = 0; j < n; j++) {
    mjtNum limit = t->torque_limit[j], bias = d->qfrc_bias[t->dof_adr[j]];
    low_Nm[j] = -limit - bias > -limit ? -limit - bias : -limit;
    high_Nm[j] = limit - bias < limit ? limit - bias : limit;
    u[j] = u[j] < low_Nm[j] ? low_Nm[j] : (u[j] > high_Nm[j] ? high_Nm[j] : u[j]);
  }
  mj_fullM(m, d, full);
  for (int i = 0; i < n; i++) {
    for (int j = 0; j < n; j++) inertia[i * n + j] = full[t->dof_adr[i] * nv + t->dof_adr[j]];
  }
  mju_copy(factor, inertia, n * n);
  mju_cholFactor(factor, n, mjMINVAL);
  mju_cholSolve(acceleration, factor, u, n);
  int inside = 1;
  for (int j = 0; j < n; j++) {
    mjtNum qdot = d->qvel[t->dof_adr[j]];
    low[j] = (-t->speed_limit[j] - qdot) / t->speed_horizon;
    high[j] = (t->speed_limit[j] - qdot) / t->speed_horizon;
    if (acceleration[j] < low[j] || acceleration[j] > high[j]) inside = 0;
  }
  if (!inside) {
    for (int j = 0; j < n; j++) clipped[j] = 0 < low[j] ? low[j] : (0 > high[j] ? high[j] : 0);
    mju_mulMatVec(rest, inertia, clipped, n, n);
    for (int j = 0; j < n; j++) {
      clipped[j] = acceleration[j] < low[j] ? low[j] : (acceleration[j] > high[j] ? high[j] : acceleration[j]);
    }
    mju_mulMatVec(step, inertia, clipped, n, n);
    mjtNum room = 1;
    for (int j = 0; j < n; j++) {
      step[j] = step[j] - rest[j];
      mjtNum ratio = room;
      if (step[j] > 0) ratio = (high_Nm[j] - rest[j]) / step[j];
      else if (step[j] < 0) ratio = (low_Nm[j] - rest[j]) / step[j];
      room = ratio < room ? ratio : room;
    }
    room = room < 0 ? 0 : room;
    for (int j = 0; j < n; j++) {
      mjtNum value = rest[j] + room * step[j];
      u[j] = value < low_Nm[j] ? low_Nm[j] : (value > high_Nm[j] ? high_Nm[j] : value);
    }
  }
  mj_freeStack(d);
}

int cito_track(const mjModel* m, mjData* d, const CitoTracking* t) {
  int nstate = mj_stateSize(m, mjSTATE_FULLPHYSICS), ns = m->nsensordata, nu = m->nu, n = t->n_joints;
  // as a fresh mjData: inputs, warmstart and warnings zero
  mj_resetData(m, d);
  mj_setState(m, d, t->initial_state, mjSTATE_FULLPHYSICS);
  mjtNum u[64];  // n_joints <= 64 (checked by the caller)
  for (int step = 0; step < t->steps; step++) {
    const mjtNum* q_ref = t->q_ref + (size_t)step * n;
    const mjtNum* qdot_ref = t->qdot_ref + (size_t)step * n;
    mjtNum* controls = t->controls + (size_t)step * nu;
    mju_zero(controls, nu);
    for (int j = 0; j < n; j++) {
      // the Python oracle's operations in its order (no contraction: -O2 without -mfma)
      mjtNum command = t->kp[j] * (q_ref[j] - d->qpos[t->qpos_adr[j]]) +
                       t->kd[j] * (qdot_ref[j] - d->qvel[t->dof_adr[j]]);
      if (t->feed_forward) command = t->feed_forward[(size_t)step * n + j] + command;
      mjtNum limit = t->torque_limit[j];
      u[j] = command < -limit ? -limit : (command > limit ? limit : command);
    }
    // with the guard, the step split around the controls: mj_step1 leaves the arm's inertia and bias forces at this
    // step's state, as the executor takes them, and mj_step2 does not compute them again
    if (t->speed_limit) {
      mj_step1(m, d);
      speed_guard(m, d, t, u);
    }
    for (int j = 0; j < n; j++) controls[t->motor_ids[j]] = u[j];
    mju_copy(d->ctrl, controls, nu);
    if (t->speed_limit) mj_step2(m, d);
    else mj_step(m, d);
    mj_getState(m, d, t->states + (size_t)step * nstate, mjSTATE_FULLPHYSICS);
    mju_copy(t->sensordata + (size_t)step * ns, d->sensordata, ns);
  }
  for (int i = 0; i < mjNWARNING; i++) t->warnings[i] = d->warning[i].number;
  return 0;
}
