// Feedback rollouts of iLQR's forward pass (see cito_native.h).
#include "cito_native.h"

#include <stdio.h>
#include <stdlib.h>

typedef struct {
  const mjModel* m;
  mjData* d;
  const CitoFeedback* f;
  int first, stride;  // the trials this job runs: first, first + stride, ...
  int failed;
} Job;

// One trial, stepped as mujoco.rollout steps an open-loop rollout of the chosen controls (inputs
// reset, warmstart zero, warnings cleared once; after a warning the remaining steps repeat the
// state reached), so that rollout reproduces it bit for bit.
static void run_trial(const mjModel* m, mjData* d, const CitoFeedback* f, int trial, mjtNum* deviation) {
  int nv = m->nv, nx = 2 * nv, ns = m->nsensordata, w = f->width, N = f->n_knots, S = f->steps_per_knot;
  int nstate = mj_stateSize(m, mjSTATE_FULLPHYSICS), qpos = mj_stateSize(m, mjSTATE_TIME);
  mjtNum alpha = f->step_lengths[trial];
  mjtNum* chosen = f->trials + (size_t)trial * N * w;
  mjtNum* states = f->states + (size_t)trial * N * S * nstate;
  mjtNum* sensordata = f->sensordata + (size_t)trial * N * S * ns;
  mj_resetData(m, d);
  mj_setState(m, d, f->initial_state, mjSTATE_FULLPHYSICS);
  mju_zero(d->qacc_warmstart, nv);
  int warned = 0;
  for (int l = 0; l < N; l++) {
    // the deviation of the state reached from the expansion's knot state, in the tangent space
    const mjtNum* reference = f->knot_states + (size_t)l * nstate;
    const mjtNum* reached = l == 0 ? f->initial_state : states + ((size_t)l * S - 1) * nstate;
    mj_differentiatePos(m, deviation, 1.0, reference + qpos, reached + qpos);
    for (int i = 0; i < nv; i++) deviation[nv + i] = reached[qpos + m->nq + i] - reference[qpos + m->nq + i];
    mjtNum* c = chosen + (size_t)l * w;
    for (int i = 0; i < w; i++) {
      const mjtNum* gain = f->K + ((size_t)l * w + i) * nx;
      mjtNum feedback = 0;
      for (int j = 0; j < nx; j++) feedback += gain[j] * deviation[j];
      mjtNum value = f->decisions[l * w + i] + alpha * f->k[l * w + i] + feedback;
      value = value < f->lower[l * w + i] ? f->lower[l * w + i] : value;
      c[i] = value > f->upper[l * w + i] ? f->upper[l * w + i] : value;
    }
    mju_zero(d->ctrl, m->nu);
    for (int i = 0; i < w; i++) {
      if (f->actuators[i] >= 0) d->ctrl[f->actuators[i]] = c[i];
    }
    for (int s = 0; s < S; s++) {
      size_t step = (size_t)l * S + s;
      if (!warned) {
        for (int i = 0; i < mjNWARNING; i++) warned |= d->warning[i].number != 0;
      }
      if (!warned) mj_step(m, d);
      mj_getState(m, d, states + step * nstate, mjSTATE_FULLPHYSICS);
      mju_copy(sensordata + step * ns, d->sensordata, ns);
    }
  }
  for (int i = 0; i < mjNWARNING; i++) f->warnings[(size_t)trial * mjNWARNING + i] = d->warning[i].number;
}

static void* run_job(void* argument) {
  Job* job = (Job*)argument;
  mjtNum* deviation = (mjtNum*)malloc(sizeof(mjtNum) * 2 * (size_t)job->m->nv);
  if (!deviation) {
    job->failed = 1;
    return NULL;
  }
  for (int trial = job->first; trial < job->f->n_trials; trial += job->stride) {
    run_trial(job->m, job->d, job->f, trial, deviation);
  }
  free(deviation);
  return NULL;
}

int cito_feedback_rollouts(const mjModel* m, mjData** datas, int nthread, const CitoFeedback* f, char* error,
                           int error_size) {
  if (nthread < 1) {
    snprintf(error, error_size, "at least one mjData is needed");
    return -1;
  }
  if (nthread > f->n_trials) nthread = f->n_trials;
  Job* jobs = (Job*)calloc(nthread > 0 ? nthread : 1, sizeof(Job));
  if (!jobs) {
    snprintf(error, error_size, "out of memory");
    return -1;
  }
  for (int i = 0; i < nthread; i++) jobs[i] = (Job){m, datas[i], f, i, nthread, 0};
  int failed = cito_run_threads(run_job, jobs, sizeof(Job), nthread);
  for (int i = 0; i < nthread; i++) failed |= jobs[i].failed;
  free(jobs);
  if (failed) {
    snprintf(error, error_size, "out of memory in the feedback rollouts");
    return -1;
  }
  return 0;
}
