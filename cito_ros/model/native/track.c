// PD joint tracking, the robot's joint trajectory controller of cito_ros.tracking (see cito_native.h).
#include "cito_native.h"

int cito_track(const mjModel* m, mjData* d, const CitoTracking* t) {
  int nstate = mj_stateSize(m, mjSTATE_FULLPHYSICS), ns = m->nsensordata, nu = m->nu, n = t->n_joints;
  // as a fresh mjData: inputs, warmstart and warnings zero
  mj_resetData(m, d);
  mj_setState(m, d, t->initial_state, mjSTATE_FULLPHYSICS);
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
      controls[t->motor_ids[j]] = command < -limit ? -limit : (command > limit ? limit : command);
    }
    mju_copy(d->ctrl, controls, nu);
    mj_step(m, d);
    mj_getState(m, d, t->states + (size_t)step * nstate, mjSTATE_FULLPHYSICS);
    mju_copy(t->sensordata + (size_t)step * ns, d->sensordata, ns);
  }
  for (int i = 0; i < mjNWARNING; i++) t->warnings[i] = d->warning[i].number;
  return 0;
}
