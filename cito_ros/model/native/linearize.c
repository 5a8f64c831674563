// Finite-difference linearization of simulation steps (see cito_native.h).
#include "cito_native.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
  const mjModel* m;
  mjData* d;
  int T;
  const mjtNum* states;
  const mjtNum* controls;
  mjtNum eps;
  const int* skip_dofs;
  int skip_steps;
  int nthread;
  int tid;
  mjtNum *A, *B, *C, *D;
  int* flags;
  int failed;
} Job;

// A contact set: geom pairs, and per contact its point (3), normal (3) and distance.
typedef struct {
  int ncon, capacity, *pairs;
  mjtNum *points, *normals, *dist;
} Contacts;

// Scratch of one thread: the nominal inputs and outputs of the step being linearized.
typedef struct {
  mjtNum *qpos, *qvel, *ctrl, time;               // nominal inputs
  mjtNum *next_qpos, *next_qvel, *sensor;         // nominal outputs
  mjtNum *plus_qpos, *plus_qvel, *plus_sensor;    // a perturbed evaluation
  mjtNum *ahead_qpos, *ahead_qvel, *ahead_sensor; // the forward one, when retrying backward
  mjtNum *dq, *column, *other;
  mjtNum *warmstart;                              // the nominal step's accelerations
  Contacts nominal, ahead;                        // the nominal contact set, the forward perturbation's
  mjtNum jump;                                    // a point moving farther has jumped
  int failed;
} Scratch;

static void restore(const mjModel* m, mjData* d, const Scratch* s) {
  mju_copy(d->qpos, s->qpos, m->nq);
  mju_copy(d->qvel, s->qvel, m->nv);
  mju_copy(d->ctrl, s->ctrl, m->nu);
  d->time = s->time;
  mju_copy(d->qacc_warmstart, s->warmstart, m->nv);
}

static void integrate(const mjModel* m, mjData* d) {
  if (m->opt.integrator == mjINT_EULER) {
    mj_Euler(m, d);
  } else {
    mj_implicit(m, d);
  }
}

// A perturbation of size eps moves a contact point by about eps times a lever arm (under a metre);
// a point that moves by more than CITO_POINT_JUMP eps has jumped (a collider choosing other points
// of a flat face or an edge), which is as discontinuous as a contact appearing; so is a normal that
// turns by more than CITO_POINT_JUMP eps (a curvature radius of 1 cm). A distance moves by
// at most eps times a lever too: one that moves by more than CITO_DEPTH_JUMP eps is a collider's
// answer that is not continuous (the convex collider's depth between nearly parallel faces, the
// arm's cylinder on the cube's top, jumps by 0.1 mm under a 1e-6 perturbation, and a difference across
// it is 1e3 times the true derivative).
#define CITO_POINT_JUMP 100
#define CITO_DEPTH_JUMP 10

static int keep_contacts(const mjData* d, Contacts* c) {
  if (d->ncon > c->capacity) {
    int* pairs = (int*)realloc(c->pairs, sizeof(int) * 2 * (size_t)d->ncon);
    if (pairs) c->pairs = pairs;
    mjtNum* points = pairs ? (mjtNum*)realloc(c->points, sizeof(mjtNum) * 3 * (size_t)d->ncon) : NULL;
    if (points) c->points = points;
    mjtNum* normals = points ? (mjtNum*)realloc(c->normals, sizeof(mjtNum) * 3 * (size_t)d->ncon) : NULL;
    if (normals) c->normals = normals;
    mjtNum* dist = normals ? (mjtNum*)realloc(c->dist, sizeof(mjtNum) * (size_t)d->ncon) : NULL;
    if (!dist) return 0;
    c->dist = dist;
    c->capacity = d->ncon;
  }
  c->ncon = d->ncon;
  for (int i = 0; i < d->ncon; i++) {
    c->pairs[2 * i] = d->contact[i].geom[0];
    c->pairs[2 * i + 1] = d->contact[i].geom[1];
    mju_copy3(c->points + 3 * i, d->contact[i].pos);
    mju_copy3(c->normals + 3 * i, d->contact[i].frame);
    c->dist[i] = d->contact[i].dist;
  }
  return 1;
}

static void free_contacts(Contacts* c) {
  free(c->pairs);
  free(c->points);
  free(c->normals);
  free(c->dist);
}

// Whether d's contacts are c's, moved by at most `jump` (points, normals) and jump / CITO_POINT_JUMP *
// CITO_DEPTH_JUMP (distances).
static int same_contacts(const mjData* d, const Contacts* c, mjtNum jump) {
  if (d->ncon != c->ncon) return 0;
  mjtNum depth_jump = jump / CITO_POINT_JUMP * CITO_DEPTH_JUMP;
  for (int i = 0; i < d->ncon; i++) {
    if (d->contact[i].geom[0] != c->pairs[2 * i] || d->contact[i].geom[1] != c->pairs[2 * i + 1]) return 0;
    mjtNum deeper = d->contact[i].dist - c->dist[i];
    if (deeper > depth_jump || deeper < -depth_jump) return 0;
    for (int k = 0; k < 3; k++) {
      mjtNum moved = d->contact[i].pos[k] - c->points[3 * i + k];
      mjtNum turned = d->contact[i].frame[k] - c->normals[3 * i + k];
      if (moved > jump || moved < -jump || turned > jump || turned < -jump) return 0;
    }
  }
  return 1;
}

// Evaluate the step from the current (perturbed) inputs, skipping stages below skipstage;
// store next state and sensors in the plus_* buffers. Returns whether the contact set is nominal;
// when `ahead` is given, keeps the contact set there.
static int evaluate(const mjModel* m, mjData* d, Scratch* s, int skipstage, Contacts* ahead) {
  mj_forwardSkip(m, d, skipstage, 0);
  int same = same_contacts(d, &s->nominal, s->jump);
  if (ahead && !keep_contacts(d, ahead)) s->failed = 1;
  mju_copy(s->plus_sensor, d->sensordata, m->nsensordata);
  integrate(m, d);
  mju_copy(s->plus_qpos, d->qpos, m->nq);
  mju_copy(s->plus_qvel, d->qvel, m->nv);
  return same;
}

// column (nx + ns) = (after - before) / h for next state (tangent space) and sensors.
static void difference(const mjModel* m, const mjtNum* qpos_before, const mjtNum* qvel_before,
                       const mjtNum* sensor_before, const mjtNum* qpos_after, const mjtNum* qvel_after,
                       const mjtNum* sensor_after, mjtNum h, mjtNum* column) {
  int nv = m->nv;
  mj_differentiatePos(m, column, h, qpos_before, qpos_after);
  for (int i = 0; i < nv; i++) column[nv + i] = (qvel_after[i] - qvel_before[i]) / h;
  for (int i = 0; i < m->nsensordata; i++) column[2 * nv + i] = (sensor_after[i] - sensor_before[i]) / h;
}

// column = other when other's first n entries (the state) are smaller in norm.
static void keep_flatter(mjtNum* column, const mjtNum* other, int n, int size) {
  if (mju_dot(other, other, n) < mju_dot(column, column, n)) mju_copy(column, other, size);
}

// Scatter column j of the stacked [x_next; s] derivative into (A or B) and (C or D).
static void scatter(const mjModel* m, const mjtNum* column, int j, int ncol, mjtNum* state_block,
                    mjtNum* sensor_block) {
  int nx = 2 * m->nv;
  for (int r = 0; r < nx; r++) state_block[r * ncol + j] = column[r];
  for (int r = 0; r < m->nsensordata; r++) sensor_block[r * ncol + j] = column[nx + r];
}

// Zero column j of A and C (a column not computed).
static void skip_column(const mjModel* m, int j, mjtNum* A, mjtNum* C) {
  int nx = 2 * m->nv;
  for (int r = 0; r < nx; r++) A[r * nx + j] = 0;
  for (int r = 0; r < m->nsensordata; r++) C[r * nx + j] = 0;
}

static void linearize_step(const mjModel* m, mjData* d, Scratch* s, const mjtNum* state,
                           const mjtNum* control, mjtNum eps, const int* skip_dofs, mjtNum* A, mjtNum* B,
                           mjtNum* C, mjtNum* D, int* flags) {
  int nv = m->nv, nu = m->nu, nx = 2 * nv;
  for (int i = 0; i < mjNWARNING; i++) d->warning[i].number = 0;
  s->jump = CITO_POINT_JUMP * eps;

  // nominal evaluation: keeps the position- and velocity-stage results for the skips below
  mj_setState(m, d, state, mjSTATE_FULLPHYSICS);
  mju_copy(d->ctrl, control, nu);
  mju_zero(d->qacc_warmstart, nv);
  mju_copy(s->qpos, d->qpos, m->nq);
  mju_copy(s->qvel, d->qvel, nv);
  mju_copy(s->ctrl, d->ctrl, nu);
  s->time = d->time;
  // The constraint solver stops within its tolerance of the solution, at a point that depends on
  // where it starts. Solved again from its own answer, the nominal step and every perturbation start
  // at the same point: the solver's residual error is common to both sides of each difference (as in
  // mjd_transitionFD), and the Newton solver, starting next to each answer, takes fewer iterations.
  mj_forward(m, d);
  mju_copy(s->warmstart, d->qacc, nv);
  mju_copy(d->qacc_warmstart, s->warmstart, nv);
  mj_forwardSkip(m, d, mjSTAGE_VEL, 0);
  if (!keep_contacts(d, &s->nominal)) {
    s->failed = 1;
    return;
  }
  mju_copy(s->sensor, d->sensordata, m->nsensordata);
  integrate(m, d);
  mju_copy(s->next_qpos, d->qpos, m->nq);
  mju_copy(s->next_qvel, d->qvel, nv);

  // controls: acceleration stage only; at an upper limit, difference inward
  for (int j = 0; j < nu; j++) {
    mjtNum h = eps;
    if (m->actuator_ctrllimited[j] && !mjDISABLED(mjDSBL_CLAMPCTRL) &&
        s->ctrl[j] + eps > m->actuator_ctrlrange[2 * j + 1]) {
      h = -eps;
    }
    restore(m, d, s);
    d->ctrl[j] += h;
    evaluate(m, d, s, mjSTAGE_VEL, NULL);
    if (h > 0) {
      difference(m, s->next_qpos, s->next_qvel, s->sensor, s->plus_qpos, s->plus_qvel, s->plus_sensor, eps, s->column);
    } else {
      difference(m, s->plus_qpos, s->plus_qvel, s->plus_sensor, s->next_qpos, s->next_qvel, s->sensor, eps, s->column);
    }
    scatter(m, s->column, j, nu, B, D);
  }

  // velocities: velocity and acceleration stages (contacts cannot change)
  for (int j = 0; j < nv; j++) {
    if (skip_dofs && skip_dofs[j]) {
      skip_column(m, nv + j, A, C);
      continue;
    }
    restore(m, d, s);
    d->qvel[j] += eps;
    evaluate(m, d, s, mjSTAGE_POS, NULL);
    difference(m, s->next_qpos, s->next_qvel, s->sensor, s->plus_qpos, s->plus_qvel, s->plus_sensor, eps, s->column);
    scatter(m, s->column, nv + j, nx, A, C);
  }

  // positions: the full pipeline; a perturbation that makes or breaks a contact is retried on
  // the other side, where the nominal contact set holds; when neither side has it but both sides
  // agree, the nominal evaluation is the collider's outlier and the central difference is smooth
  for (int j = 0; j < nv; j++) {
    if (skip_dofs && skip_dofs[j]) {
      skip_column(m, j, A, C);
      continue;
    }
    restore(m, d, s);
    mju_zero(s->dq, nv);
    s->dq[j] = 1;
    mj_integratePos(m, d->qpos, s->dq, eps);
    if (evaluate(m, d, s, mjSTAGE_NONE, &s->ahead)) {
      difference(m, s->next_qpos, s->next_qvel, s->sensor, s->plus_qpos, s->plus_qvel, s->plus_sensor, eps, s->column);
    } else {
      mju_copy(s->ahead_qpos, s->plus_qpos, m->nq);
      mju_copy(s->ahead_qvel, s->plus_qvel, nv);
      mju_copy(s->ahead_sensor, s->plus_sensor, m->nsensordata);
      restore(m, d, s);
      mj_integratePos(m, d->qpos, s->dq, -eps);
      if (evaluate(m, d, s, mjSTAGE_NONE, NULL)) {
        flags[CITO_FLAG_ONE_SIDED]++;
        difference(m, s->plus_qpos, s->plus_qvel, s->plus_sensor, s->next_qpos, s->next_qvel, s->sensor, eps, s->column);
      } else {
        difference(m, s->plus_qpos, s->plus_qvel, s->plus_sensor, s->ahead_qpos, s->ahead_qvel, s->ahead_sensor,
                   2 * eps, s->column);
        if (same_contacts(d, &s->ahead, 2 * s->jump)) {
          flags[CITO_FLAG_ONE_SIDED]++;
        } else {
          // a switch on both sides: of the three differences, the one least steep in the state is
          // the one the switches disturb least (each adds its jump / eps)
          flags[CITO_FLAG_UNRESOLVED]++;
          difference(m, s->next_qpos, s->next_qvel, s->sensor, s->ahead_qpos, s->ahead_qvel, s->ahead_sensor, eps,
                     s->other);
          keep_flatter(s->column, s->other, nx, nx + m->nsensordata);
          difference(m, s->plus_qpos, s->plus_qvel, s->plus_sensor, s->next_qpos, s->next_qvel, s->sensor, eps,
                     s->other);
          keep_flatter(s->column, s->other, nx, nx + m->nsensordata);
        }
      }
    }
    scatter(m, s->column, j, nx, A, C);
  }

  int warnings = 0;
  for (int i = 0; i < mjNWARNING; i++) warnings += d->warning[i].number;
  flags[CITO_FLAG_WARNINGS] = warnings;
}

static void* run_job(void* argument) {
  Job* job = (Job*)argument;
  const mjModel* m = job->m;
  int nv = m->nv, nu = m->nu, ns = m->nsensordata, nx = 2 * nv;
  int nstate = mj_stateSize(m, mjSTATE_FULLPHYSICS);
  mjData* d = job->d;
  mjtNum* buffer = (mjtNum*)calloc(4 * m->nq + 5 * nv + 4 * ns + nu + nv + 2 * (nx + ns) + 1, sizeof(mjtNum));
  Scratch s = {0};
  if (!buffer) {
    job->failed = 1;
  } else {
    mjtNum* p = buffer;
    s.qpos = p; p += m->nq;
    s.next_qpos = p; p += m->nq;
    s.plus_qpos = p; p += m->nq;
    s.ahead_qpos = p; p += m->nq;
    s.qvel = p; p += nv;
    s.next_qvel = p; p += nv;
    s.plus_qvel = p; p += nv;
    s.ahead_qvel = p; p += nv;
    s.sensor = p; p += ns;
    s.plus_sensor = p; p += ns;
    s.ahead_sensor = p; p += ns;
    s.ctrl = p; p += nu;
    s.dq = p; p += nv;
    s.warmstart = p; p += nv;
    s.column = p; p += nx + ns;
    s.other = p;
    for (int t = job->tid; t < job->T && !s.failed; t += job->nthread) {
      linearize_step(m, d, &s, job->states + (size_t)t * nstate, job->controls + (size_t)t * nu, job->eps,
                     t < job->skip_steps ? job->skip_dofs : NULL, job->A + (size_t)t * nx * nx,
                     job->B + (size_t)t * nx * nu,
                     job->C + (size_t)t * ns * nx, job->D + (size_t)t * ns * nu,
                     job->flags + (size_t)t * CITO_NFLAG);
    }
    job->failed = s.failed;
  }
  free_contacts(&s.nominal);
  free_contacts(&s.ahead);
  free(buffer);
  return NULL;
}

int cito_linearize(const mjModel* m, mjData** datas, int nthread, int T, const mjtNum* states,
                   const mjtNum* controls, mjtNum eps, const int* skip_dofs, int skip_steps, mjtNum* A,
                   mjtNum* B, mjtNum* C, mjtNum* D, int* flags, char* error, int error_size) {
  if (m->na) {
    snprintf(error, error_size, "models with actuator activations are not supported");
    return -1;
  }
  if (m->opt.integrator != mjINT_EULER && m->opt.integrator != mjINT_IMPLICIT &&
      m->opt.integrator != mjINT_IMPLICITFAST) {
    snprintf(error, error_size, "only the Euler and implicit integrators are supported");
    return -1;
  }
  if (nthread < 1) {
    snprintf(error, error_size, "at least one mjData is needed");
    return -1;
  }
  memset(flags, 0, sizeof(int) * (size_t)T * CITO_NFLAG);

  Job* jobs = (Job*)calloc(nthread, sizeof(Job));
  if (!jobs) {
    snprintf(error, error_size, "out of memory");
    return -1;
  }
  for (int i = 0; i < nthread; i++) {
    jobs[i] = (Job){m, datas[i], T, states, controls, eps, skip_dofs, skip_steps, nthread, i, A, B, C, D, flags,
                    0};
  }
  int failed = cito_run_threads(run_job, jobs, sizeof(Job), nthread) != 0;
  for (int i = 0; i < nthread; i++) failed |= jobs[i].failed;
  free(jobs);
  if (failed) {
    snprintf(error, error_size, "out of memory while linearizing");
    return -1;
  }
  return 0;
}
