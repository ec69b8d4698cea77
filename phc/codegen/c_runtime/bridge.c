/* phc's call bridge: a model library's functions called from Python with NumPy vectors.
 *
 * A model on the C back end (phc/codegen/c_backend.py) is a shared library of plain C
 * functions; IDA and phc's drivers call them from Python once per residual or Jacobian
 * evaluation. Through ctypes each call converts every argument (about 2 µs a call on a
 * 2-core x86-64, more when a vector is read-only, as IDA's y and ẏ are). This module does the
 * same call with the buffer protocol: it takes the function's address and the vectors, checks
 * each vector (one dimension, contiguous, float64, long enough, the output writable), releases
 * the GIL and calls the function. A vector that is not what the function needs raises
 * TypeError, ValueError or BufferError; phc's wrapper then converts it as ctypes' path does.
 *
 * It keeps no state: every call's vectors are the caller's, so threads may call at once.
 * phc compiles it once per machine, Python version and phc version, into its signed cache of
 * compiled code, and loads it as the model libraries are loaded (phc/codegen/c_bridge.py);
 * where Python's C headers are missing, the ctypes path runs and the backend line says so.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>

typedef void (*into_fn)(double, const double *, const double *, const double *, double *);
typedef void (*into_cj_fn)(double, const double *, const double *, const double *, double, double *);

/* 0 with `view` filled when `obj` is a contiguous float64 vector of at least `n` entries
   (writable when `out`), else -1 with a Python exception set (and no buffer held). */
static int vector(PyObject *obj, Py_buffer *view, Py_ssize_t n, int out, const char *what)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (out ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0)
        return -1;
    const char *f = view->format;
    if (f && (f[0] == '@' || f[0] == '=' || f[0] == '<'))
        f++;
    if (view->ndim != 1 || view->itemsize != 8 || !f || strcmp(f, "d") != 0) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_TypeError, "`%s` is not a vector of float64", what);
        return -1;
    }
    if (view->len < n * (Py_ssize_t)sizeof(double)) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_ValueError, "`%s` has %zd entries; the model's C functions need %zd", what,
                     view->len / (Py_ssize_t)sizeof(double), n);
        return -1;
    }
    return 0;
}

/* The model function at args[0] (sizes args[1..3]) into `out`; `cj_object` is NULL for
   phc_residual and phc_residual_t, phc_jacobian's cj otherwise. */
static PyObject *invoke(PyObject *const *args, PyObject *t_object, PyObject *y_object, PyObject *yp_object,
                        PyObject *p_object, PyObject *cj_object, PyObject *out_object)
{
    void *address = PyLong_AsVoidPtr(args[0]);
    Py_ssize_t n = PyLong_AsSsize_t(args[1]);
    Py_ssize_t npar = PyLong_AsSsize_t(args[2]);
    Py_ssize_t size = PyLong_AsSsize_t(args[3]);
    double cj = cj_object ? PyFloat_AsDouble(cj_object) : 0.0;
    double t = PyFloat_AsDouble(t_object);
    if (PyErr_Occurred())
        return NULL;
    if (!address) {
        PyErr_SetString(PyExc_ValueError, "no function address");
        return NULL;
    }
    Py_buffer y, yp, p, out;
    if (vector(y_object, &y, n, 0, "y") < 0)
        return NULL;
    if (vector(yp_object, &yp, n, 0, "yp") < 0)
        goto release_y;
    if (vector(p_object, &p, npar, 0, "p") < 0)
        goto release_yp;
    if (vector(out_object, &out, size, 1, "out") < 0)
        goto release_p;
    Py_BEGIN_ALLOW_THREADS
    if (cj_object)
        ((into_cj_fn)address)(t, y.buf, yp.buf, p.buf, cj, out.buf);
    else
        ((into_fn)address)(t, y.buf, yp.buf, p.buf, out.buf);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&out);
    PyBuffer_Release(&p);
    PyBuffer_Release(&yp);
    PyBuffer_Release(&y);
    Py_RETURN_NONE;
release_p:
    PyBuffer_Release(&p);
release_yp:
    PyBuffer_Release(&yp);
release_y:
    PyBuffer_Release(&y);
    return NULL;
}

/* call(address, n, npar, size, t, y, yp, p, out): phc_residual or phc_residual_t. */
static PyObject *call(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 9) {
        PyErr_SetString(PyExc_TypeError, "call() takes 9 arguments");
        return NULL;
    }
    return invoke(args, args[4], args[5], args[6], args[7], NULL, args[8]);
}

/* call_cj(address, n, npar, size, t, y, yp, p, cj, out): phc_jacobian (cj a float; anything
   else raises TypeError before the function is called). */
static PyObject *call_cj(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 10) {
        PyErr_SetString(PyExc_TypeError, "call_cj() takes 10 arguments");
        return NULL;
    }
    return invoke(args, args[4], args[5], args[6], args[7], args[8], args[9]);
}

static PyMethodDef methods[] = {
    {"call", (PyCFunction)(void (*)(void))call, METH_FASTCALL,
     "call(address, n, npar, size, t, y, yp, p, out): phc_residual or phc_residual_t into `out`"},
    {"call_cj", (PyCFunction)(void (*)(void))call_cj, METH_FASTCALL,
     "call_cj(address, n, npar, size, t, y, yp, p, cj, out): phc_jacobian into `out`"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef definition = {
    PyModuleDef_HEAD_INIT, "phc_bridge", "phc's call bridge to the C back end's model functions", -1, methods,
    NULL, NULL, NULL, NULL,
};

/* The module object (called once through ctypes with the GIL held). */
PyObject *phc_bridge_module(void)
{
    return PyModule_Create(&definition);
}
