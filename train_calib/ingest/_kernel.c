/* train_calib.ingest._kernel: a fix's position on the track inside the continuity window, in C (the same formulas
 * in the same order as the Python reference, so the same floats).
 *
 * Locator(constants, segments, vertices, hypot) with
 *   constants  (a, e2, 1 - e2, deg_to_rad, o0, o1, o2, r00, r01, r02, r10, r11, r12): geodesy.ScalarEnu's
 *              (WGS84 semi-major axis, first eccentricity squared, 1 - e2, math.radians(1.0), the frame's origin
 *              in ECEF and its east and north rows)
 *   segments   float64 bytes, 7 per segment (s0, x0, y0, ds, dx, dy, max(|d|^2, 1e-12)): track.WindowProjector's
 *   vertices   float64 bytes, the chainage s of each vertex (WindowProjector.s)
 *   hypot      math.hypot (called for each segment visited: its algorithm is CPython's own, not libm's)
 * methods
 *   enu(lat, lon) -> (east, north)            geodesy.ScalarEnu.__call__
 *   project(east, north, lo, hi) -> (s, d)    track.WindowProjector.project
 *   locate(lat, lon, lo, hi) -> (s, d)        project(*enu(lat, lon), lo, hi)
 *
 * Built with -ffp-contract=off (no fused multiply-add) and without the compiler's builtin sin/cos (no sincos
 * fusion): every operation is the Python's, sin, cos and sqrt are libm's as in Python's math module.
 * Agreement with the Python: test/test_ingest_add_many.py (random points and windows, bit for bit).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

#define N_CONSTANTS 13
#define SEGMENT_FIELDS 7

typedef struct {
    PyObject_HEAD
    double c[N_CONSTANTS];
    double *segments; /* SEGMENT_FIELDS per segment */
    double *s;        /* vertices' chainage */
    Py_ssize_t n_segments;
    PyObject *hypot;
} Locator;

static void locator_dealloc(Locator *self) {
    PyMem_Free(self->segments);
    PyMem_Free(self->s);
    Py_XDECREF(self->hypot);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static double *copy_doubles(PyObject *obj, Py_ssize_t *count, const char *name) {
    Py_buffer view;
    if (PyObject_GetBuffer(obj, &view, PyBUF_SIMPLE) < 0)
        return NULL;
    if (view.len % (Py_ssize_t)sizeof(double) != 0) {
        PyBuffer_Release(&view);
        PyErr_Format(PyExc_ValueError, "%s: not float64 bytes", name);
        return NULL;
    }
    *count = view.len / (Py_ssize_t)sizeof(double);
    double *out = PyMem_Malloc(view.len > 0 ? (size_t)view.len : 1);
    if (out == NULL) {
        PyBuffer_Release(&view);
        PyErr_NoMemory();
        return NULL;
    }
    memcpy(out, view.buf, (size_t)view.len);
    PyBuffer_Release(&view);
    return out;
}

static PyObject *locator_new(PyTypeObject *type, PyObject *args, PyObject *kwargs) {
    PyObject *constants, *segments, *vertices, *hypot;
    static char *names[] = {"constants", "segments", "vertices", "hypot", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwargs, "OOOO", names, &constants, &segments, &vertices, &hypot))
        return NULL;
    PyObject *seq = PySequence_Fast(constants, "constants: a sequence of floats");
    if (seq == NULL)
        return NULL;
    if (PySequence_Fast_GET_SIZE(seq) != N_CONSTANTS) {
        Py_DECREF(seq);
        PyErr_Format(PyExc_ValueError, "constants: %d floats", N_CONSTANTS);
        return NULL;
    }
    Locator *self = (Locator *)type->tp_alloc(type, 0);
    if (self == NULL) {
        Py_DECREF(seq);
        return NULL;
    }
    for (int i = 0; i < N_CONSTANTS; i++) {
        self->c[i] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(seq, i));
        if (self->c[i] == -1.0 && PyErr_Occurred()) {
            Py_DECREF(seq);
            Py_DECREF(self);
            return NULL;
        }
    }
    Py_DECREF(seq);
    Py_ssize_t n_fields, n_vertices;
    self->segments = copy_doubles(segments, &n_fields, "segments");
    if (self->segments == NULL) {
        Py_DECREF(self);
        return NULL;
    }
    self->s = copy_doubles(vertices, &n_vertices, "vertices");
    if (self->s == NULL) {
        Py_DECREF(self);
        return NULL;
    }
    if (n_fields % SEGMENT_FIELDS != 0 || n_vertices < 2 || n_fields / SEGMENT_FIELDS != n_vertices - 1) {
        Py_DECREF(self);
        PyErr_SetString(PyExc_ValueError, "segments: 7 floats per segment, one segment per pair of vertices");
        return NULL;
    }
    self->n_segments = n_vertices - 1;
    if (!PyCallable_Check(hypot)) {
        Py_DECREF(self);
        PyErr_SetString(PyExc_TypeError, "hypot: not callable");
        return NULL;
    }
    Py_INCREF(hypot);
    self->hypot = hypot;
    return (PyObject *)self;
}

/* A float argument as Python's math functions take it (a float or an int). */
static int as_double(PyObject *obj, double *out) {
    if (PyFloat_CheckExact(obj)) {
        *out = PyFloat_AS_DOUBLE(obj);
        return 1;
    }
    *out = PyFloat_AsDouble(obj);
    return !(*out == -1.0 && PyErr_Occurred());
}

/* geodesy.ScalarEnu.__call__ */
static void enu(const double *c, double lat, double lon, double *east, double *north) {
    const double a = c[0], e2 = c[1], one_minus_e2 = c[2], deg_to_rad = c[3];
    double lat_r = lat * deg_to_rad, lon_r = lon * deg_to_rad; /* math.radians */
    double sin_lat = sin(lat_r), cos_lat = cos(lat_r);
    double n = a / sqrt(1.0 - e2 * sin_lat * sin_lat);
    double d0 = n * cos_lat * cos(lon_r) - c[4];
    double d1 = n * cos_lat * sin(lon_r) - c[5];
    double d2 = n * one_minus_e2 * sin_lat - c[6];
    *east = c[7] * d0 + c[8] * d1 + c[9] * d2;
    *north = c[10] * d0 + c[11] * d1 + c[12] * d2;
}

/* bisect.bisect_right / bisect_left on the vertices (the same comparisons) */
static Py_ssize_t bisect_right(const double *a, Py_ssize_t n, double x) {
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (x < a[mid])
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

static Py_ssize_t bisect_left(const double *a, Py_ssize_t n, double x) {
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (a[mid] < x)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* math.hypot(x, y) through the Python function; 0 on an error (set) */
static int call_hypot(PyObject *hypot, double x, double y, double *out) {
    PyObject *args[2];
    args[0] = PyFloat_FromDouble(x);
    if (args[0] == NULL)
        return 0;
    args[1] = PyFloat_FromDouble(y);
    if (args[1] == NULL) {
        Py_DECREF(args[0]);
        return 0;
    }
    PyObject *r = PyObject_Vectorcall(hypot, args, 2, NULL);
    Py_DECREF(args[0]);
    Py_DECREF(args[1]);
    if (r == NULL)
        return 0;
    int ok = as_double(r, out);
    Py_DECREF(r);
    return ok;
}

/* track.WindowProjector.project */
static PyObject *project(Locator *self, double e, double n, double lo, double hi) {
    const double *s = self->s;
    Py_ssize_t segments = self->n_segments;
    double start = s[0], end = s[segments];
    lo = start > lo ? start : lo;
    hi = end < hi ? end : hi;
    if (hi < lo)
        lo = hi = hi < start ? start : end;
    Py_ssize_t first = bisect_right(s, segments + 1, lo) - 1;
    first = first < 0 ? 0 : first > segments - 1 ? segments - 1 : first;
    Py_ssize_t stop = bisect_left(s, segments + 1, hi);
    stop = stop < first + 1 ? first + 1 : stop > segments ? segments : stop;
    double best_s = lo, best_d = Py_HUGE_VAL;
    for (Py_ssize_t i = first; i < stop; i++) {
        const double *g = self->segments + SEGMENT_FIELDS * i;
        double s0 = g[0], x0 = g[1], y0 = g[2], ds = g[3], dx = g[4], dy = g[5], len2 = g[6];
        double t = ((e - x0) * dx + (n - y0) * dy) / len2;
        t = t < 0.0 ? 0.0 : t > 1.0 ? 1.0 : t;
        double si = s0 + t * ds;
        si = si < lo ? lo : si > hi ? hi : si;
        double f = ds > 0 ? (si - s0) / ds : 0.0;
        double d;
        if (!call_hypot(self->hypot, x0 + f * dx - e, y0 + f * dy - n, &d))
            return NULL;
        if (d < best_d) {
            best_s = si;
            best_d = d;
        }
    }
    return Py_BuildValue("(dd)", best_s, best_d);
}

static PyObject *locator_enu(Locator *self, PyObject *const *args, Py_ssize_t nargs) {
    double lat, lon, east, north;
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "enu(lat, lon)");
        return NULL;
    }
    if (!as_double(args[0], &lat) || !as_double(args[1], &lon))
        return NULL;
    enu(self->c, lat, lon, &east, &north);
    return Py_BuildValue("(dd)", east, north);
}

static PyObject *locator_project(Locator *self, PyObject *const *args, Py_ssize_t nargs) {
    double v[4];
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "project(east, north, lo, hi)");
        return NULL;
    }
    for (int i = 0; i < 4; i++)
        if (!as_double(args[i], &v[i]))
            return NULL;
    return project(self, v[0], v[1], v[2], v[3]);
}

static PyObject *locator_locate(Locator *self, PyObject *const *args, Py_ssize_t nargs) {
    double v[4], east, north;
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "locate(lat, lon, lo, hi)");
        return NULL;
    }
    for (int i = 0; i < 4; i++)
        if (!as_double(args[i], &v[i]))
            return NULL;
    enu(self->c, v[0], v[1], &east, &north);
    return project(self, east, north, v[2], v[3]);
}

static PyMethodDef locator_methods[] = {
    {"enu", (PyCFunction)(void (*)(void))locator_enu, METH_FASTCALL,
     "enu(lat, lon) -> (east, north): degrees to the frame's east and north in m (geodesy.ScalarEnu)."},
    {"project", (PyCFunction)(void (*)(void))locator_project, METH_FASTCALL,
     "project(east, north, lo, hi) -> (s, d): the nearest track point with s in [lo, hi] (m), its distance "
     "(track.WindowProjector.project)."},
    {"locate", (PyCFunction)(void (*)(void))locator_locate, METH_FASTCALL,
     "locate(lat, lon, lo, hi) -> (s, d): project(*enu(lat, lon), lo, hi)."},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject LocatorType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "train_calib.ingest._kernel.Locator",
    .tp_basicsize = sizeof(Locator),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "A fix's ENU position and its projection onto the track within a window (see the module).",
    .tp_new = locator_new,
    .tp_dealloc = (destructor)locator_dealloc,
    .tp_methods = locator_methods,
};

static struct PyModuleDef kernel_module = {
    PyModuleDef_HEAD_INIT, "_kernel", "The ingest's compiled kernel: map matching in the window (see offline.py).",
    -1, NULL, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__kernel(void) {
    if (PyType_Ready(&LocatorType) < 0)
        return NULL;
    PyObject *module = PyModule_Create(&kernel_module);
    if (module == NULL)
        return NULL;
    Py_INCREF(&LocatorType);
    if (PyModule_AddObject(module, "Locator", (PyObject *)&LocatorType) < 0) {
        Py_DECREF(&LocatorType);
        Py_DECREF(module);
        return NULL;
    }
    return module;
}
