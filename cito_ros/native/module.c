// The CPython extension module cito_ros._native. Importing it registers the MuJoCo engine
// plugins (once per process: Python imports a module once); `linearize` wraps cito_linearize.
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

static PyObject* linearize(PyObject* self, PyObject* args) {
  (void)self;
  unsigned long long address;
  int T;
  double eps;
  PyObject *data_addresses, *states, *controls, *A, *B, *C, *D, *flags;
  if (!PyArg_ParseTuple(args, "KOiOOdOOOOO", &address, &data_addresses, &T, &states, &controls, &eps, &A,
                        &B, &C, &D, &flags)) {
    return NULL;
  }
  const mjModel* m = (const mjModel*)(uintptr_t)address;
  if (!m || T < 0 || !PyTuple_Check(data_addresses) || PyTuple_GET_SIZE(data_addresses) < 1) {
    PyErr_SetString(PyExc_ValueError, "need a model address, a non-empty tuple of mjData addresses, T >= 0");
    return NULL;
  }
  int nthread = (int)PyTuple_GET_SIZE(data_addresses);
  mjData* datas[64];
  if (nthread > 64) nthread = 64;
  for (int i = 0; i < nthread; i++) {
    datas[i] = (mjData*)(uintptr_t)PyLong_AsUnsignedLongLong(PyTuple_GET_ITEM(data_addresses, i));
    if (PyErr_Occurred() || !datas[i]) {
      PyErr_SetString(PyExc_ValueError, "invalid mjData address");
      return NULL;
    }
  }
  Py_ssize_t nx = 2 * m->nv, nu = m->nu, ns = m->nsensordata;
  Py_ssize_t nstate = mj_stateSize(m, mjSTATE_FULLPHYSICS);
  Py_buffer views[7];
  struct { PyObject* object; Py_ssize_t count; int writable; char format; const char* name; } specs[7] = {
    {states, T * nstate, 0, 'd', "states"}, {controls, T * nu, 0, 'd', "controls"},
    {A, T * nx * nx, 1, 'd', "A"}, {B, T * nx * nu, 1, 'd', "B"}, {C, T * ns * nx, 1, 'd', "C"},
    {D, T * ns * nu, 1, 'd', "D"}, {flags, T * CITO_NFLAG, 1, 'i', "flags"},
  };
  int acquired = 0;
  for (; acquired < 7; acquired++) {
    if (get_buffer(specs[acquired].object, &views[acquired], specs[acquired].count, specs[acquired].writable,
                   specs[acquired].format, specs[acquired].name) != 0) {
      break;
    }
  }
  int status = 0;
  char error[256] = "";
  if (acquired == 7) {
    Py_BEGIN_ALLOW_THREADS
    status = cito_linearize(m, datas, nthread, T, views[0].buf, views[1].buf, eps, views[2].buf,
                            views[3].buf, views[4].buf, views[5].buf, views[6].buf, error, sizeof(error));
    Py_END_ALLOW_THREADS
  }
  for (int i = 0; i < acquired; i++) PyBuffer_Release(&views[i]);
  if (acquired < 7) return NULL;
  if (status != 0) {
    PyErr_SetString(PyExc_RuntimeError, error);
    return NULL;
  }
  Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
  {"linearize", linearize, METH_VARARGS,
   "linearize(model_address, data_addresses, T, states, controls, eps, A, B, C, D, flags)\n"
   "Finite-difference linearization of T steps into the preallocated arrays, one thread per\n"
   "mjData in the tuple data_addresses (see cito_native.h)."},
  {NULL, NULL, 0, NULL},
};

static struct PyModuleDef native_module = {
  PyModuleDef_HEAD_INIT, "_native",
  "MuJoCo engine plugins cito.compensated_motor and cito.virtual_contact (registered on import), "
  "and the native per-step linearization.",
  -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__native(void) {
  cito_register_plugins();
  return PyModule_Create(&native_module);
}
