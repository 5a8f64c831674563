// The CPython extension module cito_ros.model._native. Importing it registers the MuJoCo engine
// plugins (once per process: Python imports a module once); `linearize` wraps cito_linearize,
// `feedback_rollouts` cito_feedback_rollouts, `track` cito_track.
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "cito_native.h"

// A C-contiguous float64 (or int32) buffer of exactly `count` items, or NULL with an exception.
static int get_buffer(PyObject* object, Py_buffer* view, Py_ssize_t count, int writable, char format,
                      const char* name) {
  int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
  if (PyObject_GetBuffer(object, view, flags) != 0) return -1;
  Py_ssize_t itemsize = format == 'd' ? (Py_ssize_t)sizeof(double) : (Py_ssize_t)sizeof(int);
  if (view->itemsize != itemsize || !view->format || view->format[0] != format ||
      view->len != count * itemsize) {
    PyErr_Format(PyExc_ValueError, "%s must be a C-contiguous %s array of %zd items", name,
                 format == 'd' ? "float64" : "int32", count);
    PyBuffer_Release(view);
    return -1;
  }
  return 0;
}

// The model (non-NULL) and its mjData addresses (a non-empty tuple, at most 64 used): the number
// of mjData, or 0 with an exception.
static int get_datas(const mjModel* m, PyObject* data_addresses, mjData** datas) {
  if (!m || !PyTuple_Check(data_addresses) || PyTuple_GET_SIZE(data_addresses) < 1) {
    PyErr_SetString(PyExc_ValueError, "need a model address and a non-empty tuple of mjData addresses");
    return 0;
  }
  int nthread = (int)PyTuple_GET_SIZE(data_addresses);
  if (nthread > 64) nthread = 64;
  for (int i = 0; i < nthread; i++) {
    datas[i] = (mjData*)(uintptr_t)PyLong_AsUnsignedLongLong(PyTuple_GET_ITEM(data_addresses, i));
    if (PyErr_Occurred() || !datas[i]) {
      PyErr_Clear();
      PyErr_SetString(PyExc_ValueError, "invalid mjData address");
      return 0;
    }
  }
  return nthread;
}

static PyObject* linearize(PyObject* self, PyObject* args) {
  (void)self;
  unsigned long long address;
  int T, skip_steps;
  double eps;
  PyObject *data_addresses, *states, *controls, *skip_dofs, *A, *B, *C, *D, *flags;
  if (!PyArg_ParseTuple(args, "KOiOOdOiOOOOO", &address, &data_addresses, &T, &states, &controls, &eps,
                        &skip_dofs, &skip_steps, &A, &B, &C, &D, &flags)) {
    return NULL;
  }
  const mjModel* m = (const mjModel*)(uintptr_t)address;
  mjData* datas[64];
  int nthread = get_datas(m, data_addresses, datas);
  if (nthread < 1) return NULL;
  if (T < 0) {
    PyErr_SetString(PyExc_ValueError, "T must be >= 0");
    return NULL;
  }
  Py_ssize_t nx = 2 * m->nv, nu = m->nu, ns = m->nsensordata;
  Py_ssize_t nstate = mj_stateSize(m, mjSTATE_FULLPHYSICS);
  Py_buffer views[8];
  struct { PyObject* object; Py_ssize_t count; int writable; char format; const char* name; } specs[8] = {
    {states, T * nstate, 0, 'd', "states"}, {controls, T * nu, 0, 'd', "controls"},
    {skip_dofs, m->nv, 0, 'i', "skip_dofs"},
    {A, T * nx * nx, 1, 'd', "A"}, {B, T * nx * nu, 1, 'd', "B"}, {C, T * ns * nx, 1, 'd', "C"},
    {D, T * ns * nu, 1, 'd', "D"}, {flags, T * CITO_NFLAG, 1, 'i', "flags"},
  };
  int acquired = 0;
  for (; acquired < 8; acquired++) {
    if (get_buffer(specs[acquired].object, &views[acquired], specs[acquired].count, specs[acquired].writable,
                   specs[acquired].format, specs[acquired].name) != 0) {
      break;
    }
  }
  int status = 0;
  char error[256] = "";
  if (acquired == 8) {
    Py_BEGIN_ALLOW_THREADS
    status = cito_linearize(m, datas, nthread, T, views[0].buf, views[1].buf, eps, views[2].buf, skip_steps,
                            views[3].buf, views[4].buf, views[5].buf, views[6].buf, views[7].buf, error,
                            sizeof(error));
    Py_END_ALLOW_THREADS
  }
  for (int i = 0; i < acquired; i++) PyBuffer_Release(&views[i]);
  if (acquired < 8) return NULL;
  if (status != 0) {
    PyErr_SetString(PyExc_RuntimeError, error);
    return NULL;
  }
  Py_RETURN_NONE;
}

static PyObject* feedback_rollouts(PyObject* self, PyObject* args) {
  (void)self;
  unsigned long long address;
  CitoFeedback f;
  PyObject *data_addresses, *initial_state, *knot_states, *decisions, *k, *K, *step_lengths, *lower, *upper,
      *actuators, *trials, *states, *sensordata, *warnings;
  if (!PyArg_ParseTuple(args, "KOiiiiOOOOOOOOOOOOO", &address, &data_addresses, &f.n_trials, &f.n_knots,
                        &f.steps_per_knot, &f.width, &initial_state, &knot_states, &decisions, &k, &K,
                        &step_lengths, &lower, &upper, &actuators, &trials, &states, &sensordata, &warnings)) {
    return NULL;
  }
  const mjModel* m = (const mjModel*)(uintptr_t)address;
  mjData* datas[64];
  int nthread = get_datas(m, data_addresses, datas);
  if (nthread < 1) return NULL;
  if (f.n_trials < 0 || f.n_knots < 0 || f.steps_per_knot < 0 || f.width < 0) {
    PyErr_SetString(PyExc_ValueError, "n_trials, n_knots, steps_per_knot and width must be >= 0");
    return NULL;
  }
  Py_ssize_t nx = 2 * m->nv, ns = m->nsensordata, nstate = mj_stateSize(m, mjSTATE_FULLPHYSICS);
  Py_ssize_t trial_count = f.n_trials, N = f.n_knots, w = f.width, steps = N * f.steps_per_knot;
  Py_buffer views[13];
  // each buffer, and the member of f that points at it
  struct { PyObject* object; Py_ssize_t count; int writable; char format; const char* name; void* member; } specs[13] = {
    {initial_state, nstate, 0, 'd', "initial_state", &f.initial_state},
    {knot_states, N * nstate, 0, 'd', "knot_states", &f.knot_states},
    {decisions, N * w, 0, 'd', "decisions", &f.decisions}, {k, N * w, 0, 'd', "k", &f.k},
    {K, N * w * nx, 0, 'd', "K", &f.K}, {step_lengths, trial_count, 0, 'd', "step_lengths", &f.step_lengths},
    {lower, N * w, 0, 'd', "lower", &f.lower}, {upper, N * w, 0, 'd', "upper", &f.upper},
    {actuators, w, 0, 'i', "actuators", &f.actuators},
    {trials, trial_count * N * w, 1, 'd', "trials", &f.trials},
    {states, trial_count * steps * nstate, 1, 'd', "states", &f.states},
    {sensordata, trial_count * steps * ns, 1, 'd', "sensordata", &f.sensordata},
    {warnings, trial_count * mjNWARNING, 1, 'i', "warnings", &f.warnings},
  };
  int acquired = 0;
  for (; acquired < 13; acquired++) {
    if (get_buffer(specs[acquired].object, &views[acquired], specs[acquired].count, specs[acquired].writable,
                   specs[acquired].format, specs[acquired].name) != 0) {
      break;
    }
  }
  int status = 0, invalid = -1;
  char error[256] = "";
  for (int i = 0; acquired == 13 && i < w && invalid < 0; i++) {
    int actuator = ((const int*)views[8].buf)[i];
    if (actuator < -1 || actuator >= m->nu) invalid = i;
  }
  if (invalid >= 0) {
    PyErr_Format(PyExc_ValueError, "actuators[%d] = %d is not an actuator of the model (nor -1)", invalid,
                 ((const int*)views[8].buf)[invalid]);
  }
  if (acquired == 13 && invalid < 0) {
    for (int i = 0; i < 13; i++) *(void**)specs[i].member = views[i].buf;
    Py_BEGIN_ALLOW_THREADS
    status = cito_feedback_rollouts(m, datas, nthread, &f, error, sizeof(error));
    Py_END_ALLOW_THREADS
  }
  for (int i = 0; i < acquired; i++) PyBuffer_Release(&views[i]);
  if (acquired < 13 || invalid >= 0) return NULL;
  if (status != 0) {
    PyErr_SetString(PyExc_RuntimeError, error);
    return NULL;
  }
  Py_RETURN_NONE;
}

static PyObject* track(PyObject* self, PyObject* args) {
  (void)self;
  unsigned long long model_address, data_address;
  CitoTracking t;
  PyObject *initial_state, *q_ref, *qdot_ref, *kp, *kd, *torque_limit, *qpos_adr, *dof_adr, *motor_ids, *states,
      *sensordata, *controls, *warnings, *feed_forward, *speed_limit;
  if (!PyArg_ParseTuple(args, "KKiiOOOOOOOOOOOOOOOd", &model_address, &data_address, &t.steps, &t.n_joints,
                        &initial_state, &q_ref, &qdot_ref, &kp, &kd, &torque_limit, &qpos_adr, &dof_adr,
                        &motor_ids, &states, &sensordata, &controls, &warnings, &feed_forward, &speed_limit,
                        &t.speed_horizon)) {
    return NULL;
  }
  const mjModel* m = (const mjModel*)(uintptr_t)model_address;
  mjData* d = (mjData*)(uintptr_t)data_address;
  if (!m || !d || t.steps < 0 || t.n_joints < 0 || t.n_joints > 64) {
    PyErr_SetString(PyExc_ValueError, "need model and mjData addresses, steps >= 0 and 0 <= n_joints <= 64");
    return NULL;
  }
  if (speed_limit != Py_None && !(t.speed_horizon > 0)) {
    PyErr_SetString(PyExc_ValueError, "a speed guard needs speed_horizon > 0");
    return NULL;
  }
  Py_ssize_t nstate = mj_stateSize(m, mjSTATE_FULLPHYSICS), steps = t.steps, n = t.n_joints;
  t.feed_forward = NULL;
  t.speed_limit = NULL;
  Py_buffer views[15];
  // each buffer, and the member of t that points at it (the optional ones last: None leaves them NULL)
  typedef struct { PyObject* object; Py_ssize_t count; int writable; char format; const char* name; void* member; } Spec;
  Spec specs[15] = {
    {initial_state, nstate, 0, 'd', "initial_state", &t.initial_state},
    {q_ref, steps * n, 0, 'd', "q_ref", &t.q_ref}, {qdot_ref, steps * n, 0, 'd', "qdot_ref", &t.qdot_ref},
    {kp, n, 0, 'd', "kp", &t.kp}, {kd, n, 0, 'd', "kd", &t.kd}, {torque_limit, n, 0, 'd', "torque_limit", &t.torque_limit},
    {qpos_adr, n, 0, 'i', "qpos_adr", &t.qpos_adr}, {dof_adr, n, 0, 'i', "dof_adr", &t.dof_adr},
    {motor_ids, n, 0, 'i', "motor_ids", &t.motor_ids},
    {states, steps * nstate, 1, 'd', "states", &t.states},
    {sensordata, steps * m->nsensordata, 1, 'd', "sensordata", &t.sensordata},
    {controls, steps * m->nu, 1, 'd', "controls", &t.controls},
    {warnings, mjNWARNING, 1, 'i', "warnings", &t.warnings},
    {feed_forward, steps * n, 0, 'd', "feed_forward", &t.feed_forward},
    {speed_limit, n, 0, 'd', "speed_limit", &t.speed_limit},
  };
  int nview = 0;  // the buffers given: the 13 required, then the optional ones not None
  Spec given[15];
  for (int i = 0; i < 15; i++) {
    if (i < 13 || specs[i].object != Py_None) given[nview++] = specs[i];
  }
  int acquired = 0;
  for (; acquired < nview; acquired++) {
    if (get_buffer(given[acquired].object, &views[acquired], given[acquired].count, given[acquired].writable,
                   given[acquired].format, given[acquired].name) != 0) {
      break;
    }
  }
  const char* invalid = NULL;
  for (int j = 0; acquired == nview && j < n && !invalid; j++) {
    if (((const int*)views[6].buf)[j] < 0 || ((const int*)views[6].buf)[j] >= m->nq) invalid = "qpos_adr";
    else if (((const int*)views[7].buf)[j] < 0 || ((const int*)views[7].buf)[j] >= m->nv) invalid = "dof_adr";
    else if (((const int*)views[8].buf)[j] < 0 || ((const int*)views[8].buf)[j] >= m->nu) invalid = "motor_ids";
  }
  if (invalid) PyErr_Format(PyExc_ValueError, "%s has an index outside the model", invalid);
  if (acquired == nview && !invalid) {
    for (int i = 0; i < nview; i++) *(void**)given[i].member = views[i].buf;
    Py_BEGIN_ALLOW_THREADS
    cito_track(m, d, &t);
    Py_END_ALLOW_THREADS
  }
  for (int i = 0; i < acquired; i++) PyBuffer_Release(&views[i]);
  if (acquired < nview || invalid) return NULL;
  Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
  {"linearize", linearize, METH_VARARGS,
   "linearize(model_address, data_addresses, T, states, controls, eps, skip_dofs, skip_steps, A, B, C, D,\n"
   "flags)\n"
   "Finite-difference linearization of T steps into the preallocated arrays, one thread per\n"
   "mjData in the tuple data_addresses (see cito_native.h)."},
  {"feedback_rollouts", feedback_rollouts, METH_VARARGS,
   "feedback_rollouts(model_address, data_addresses, n_trials, n_knots, steps_per_knot, width,\n"
   "initial_state, knot_states, decisions, k, K, step_lengths, lower, upper, actuators, trials, states,\n"
   "sensordata, warnings)\n"
   "iLQR's forward pass: feedback rollouts side by side, one thread per mjData in data_addresses,\n"
   "outputs into the preallocated arrays (see cito_native.h)."},
  {"track", track, METH_VARARGS,
   "track(model_address, data_address, steps, n_joints, initial_state, q_ref, qdot_ref, kp, kd, torque_limit,\n"
   "qpos_adr, dof_adr, motor_ids, states, sensordata, controls, warnings, feed_forward, speed_limit,\n"
   "speed_horizon)\n"
   "PD joint tracking of q_ref, qdot_ref (plus feed_forward, or None; through the speed guard at\n"
   "speed_limit, or None) in the mjData, outputs into the\n"
   "preallocated arrays (see cito_native.h)."},
  {NULL, NULL, 0, NULL},
};

static struct PyModuleDef native_module = {
  PyModuleDef_HEAD_INIT, "_native",
  "MuJoCo engine plugins cito.compensated_motor and cito.virtual_contact (registered on import), "
  "the native per-step linearization and iLQR's feedback rollouts.",
  -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__native(void) {
  cito_register_plugins();
  return PyModule_Create(&native_module);
}
