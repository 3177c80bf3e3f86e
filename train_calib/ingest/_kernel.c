/* train_calib.ingest._kernel: a fix's position on the track inside the continuity window, in C (the same formulas
 * in the same order as the Python reference, so the same floats), and the decoding of a bag's input messages.
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
 *
 * chunk_events(records, kinds, classes, nan, check_channel, check_schema): cdr_inputs' decoding of the input
 * messages among an MCAP chunk's records (below); agreement: test/test_cdr_inputs.py (every test both ways, and
 * chunks with random bytes changed).
 *
 * Memory check after a change (the tests on an ASan/UBSan build, then the normal build back):
 *   gcc -O1 -g -std=c99 -ffp-contract=off -fno-builtin -fsanitize=address,undefined -fPIC -shared -I"$(.venv/bin/python
 *     -c 'import sysconfig; print(sysconfig.get_paths()["include"])')" train_calib/ingest/_kernel.c
 *     -o train_calib/ingest/_kernel.cpython-311-x86_64-linux-gnu.so
 *   ASAN_OPTIONS=detect_leaks=0 LD_PRELOAD="$(gcc -print-file-name=libasan.so):$(gcc -print-file-name=libubsan.so)"
 *     .venv/bin/python -m pytest -n0 -p no:cacheprovider test/test_ingest_add_many.py test/test_cdr_inputs.py
 *   .venv/bin/python setup.py -q build_ext --inplace --force   (the normal build again)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
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

/* ---- cdr_inputs: the input messages of an MCAP chunk's records ------------------------------------------------
 *
 * chunk_events(records, kinds, classes, nan, check_channel, check_schema) -> list of (log time, event), or None
 * where cdr_inputs._chunk_events raises _Unusable: its loop over the records and _Decoder's messages (the same
 * checks, the same fields, the same events: classes = (GnssFix, SpeedSample, PowerSample) called with the values
 * _Decoder.fix / speed / power pass them; nan = math.nan, the unknown variance); a channel or schema record goes to
 * check_channel / check_schema(records, pos, end) (cdr_inputs' own, which raise _Unusable: passed on). */

static uint64_t u64_at(const unsigned char *b) {
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--)
        v = (v << 8) | b[i];
    return v;
}

static uint32_t u32_at(const unsigned char *b) { return (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24; }

static double f64_at(const unsigned char *b) {
    uint64_t bits = u64_at(b);
    double v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

/* _Decoder._values' checks and _layout's offsets: 1 and the message's fields' offset (from its start at pos), 0
 * where _Decoder raises _Unusable (-1: a Python error). floats: offset of the first float64 field. */
static int message_layout(const unsigned char *b, Py_ssize_t pos, Py_ssize_t end, int kind, Py_ssize_t *cdr_out,
                          Py_ssize_t *floats_out) {
    if (end - pos < 16)
        return 0;
    uint32_t length = u32_at(b + pos + 12);
    if (length < 1)
        return 0;
    long long cdr = 12 + (long long)length, floats, stop;
    if (kind == 0) {
        long long service = (cdr + 2) & -2;
        floats = (service + 2 + 7) & -8;
        stop = floats + 97;
    } else {
        floats = (cdr + 7) & -8;
        stop = floats + (kind == 1 ? 48 : 16);
    }
    long long size = 4 + stop, have = (long long)(end - pos);
    if (!(size <= have && have <= size + 3))
        return 0;
    const unsigned char *frame = b + pos + 16;
    if (b[pos] != 0x00 || b[pos + 1] != 0x01 || frame[length - 1] != 0)
        return 0; /* not little-endian CDR, or no terminator */
    PyObject *text = PyUnicode_DecodeUTF8((const char *)frame, (Py_ssize_t)length - 1, NULL);
    if (text == NULL) {
        if (!PyErr_ExceptionMatches(PyExc_UnicodeDecodeError))
            return -1;
        PyErr_Clear();
        return 0;
    }
    Py_DECREF(text);
    *cdr_out = (Py_ssize_t)cdr;
    *floats_out = (Py_ssize_t)floats;
    return 1;
}

/* _Decoder.fix / speed / power: the event of the message at pos..end; NULL with an error, or Py_None (borrowed)
 * where _Decoder raises _Unusable */
static PyObject *message_event(const unsigned char *b, Py_ssize_t pos, Py_ssize_t end, int kind, PyObject *classes,
                               double nan_value) {
    Py_ssize_t cdr, floats;
    int ok = message_layout(b, pos, end, kind, &cdr, &floats);
    if (ok <= 0)
        return ok < 0 ? NULL : Py_None;
    const unsigned char *m = b + pos + 4; /* after the encapsulation: the layout's offsets */
    int32_t sec = (int32_t)u32_at(b + pos + 4);
    uint32_t nanosec = u32_at(b + pos + 8);
    PyObject *args[6] = {NULL, NULL, NULL, NULL, NULL, NULL};
    int n = 0;
    args[n++] = PyLong_FromLongLong((long long)sec * 1000000000LL + (long long)nanosec); /* v[1] * NS + v[2] */
    if (kind == 0) {
        int status = (int)(signed char)m[cdr];
        double lat = f64_at(m + floats), lon = f64_at(m + floats + 8);
        double c0 = f64_at(m + floats + 24), c4 = f64_at(m + floats + 24 + 4 * 8);
        int known = m[floats + 96] != 0; /* position_covariance_type != COVARIANCE_TYPE_UNKNOWN */
        double variance = known ? 0.5 * (c0 + c4) : nan_value;
        args[n++] = PyFloat_FromDouble(lat);
        args[n++] = PyFloat_FromDouble(lon);
        args[n++] = PyLong_FromLong(status);
        args[n++] = PyFloat_FromDouble(variance);
        args[n] = known ? Py_True : Py_False;
        Py_INCREF(args[n]);
        n++;
    } else {
        args[n++] = PyFloat_FromDouble(f64_at(m + floats));
        if (kind == 2)
            args[n++] = PyFloat_FromDouble(f64_at(m + floats + 8));
    }
    PyObject *event = NULL;
    for (int i = 0; i < n; i++)
        if (args[i] == NULL)
            goto done;
    event = PyObject_Vectorcall(PyTuple_GET_ITEM(classes, kind), args, (size_t)n, NULL);
done:
    for (int i = 0; i < n; i++)
        Py_XDECREF(args[i]);
    return event;
}

static PyObject *kernel_chunk_events(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
    (void)module;
    if (nargs != 6 || !PyBytes_Check(args[0]) || !PyDict_Check(args[1]) || !PyTuple_Check(args[2]) ||
        PyTuple_GET_SIZE(args[2]) != 3 || !PyFloat_Check(args[3])) {
        PyErr_SetString(PyExc_TypeError,
                        "chunk_events(records: bytes, kinds: dict, classes: 3-tuple, nan: float, check_channel, "
                        "check_schema)");
        return NULL;
    }
    PyObject *records = args[0], *kinds = args[1], *classes = args[2];
    double nan_value = PyFloat_AS_DOUBLE(args[3]);
    const unsigned char *b = (const unsigned char *)PyBytes_AS_STRING(records);
    Py_ssize_t n = PyBytes_GET_SIZE(records), pos = 0;
    PyObject *out = PyList_New(0);
    if (out == NULL)
        return NULL;
    while (pos < n) {
        if (pos + 9 > n)
            goto unusable;
        int opcode = b[pos];
        uint64_t length = u64_at(b + pos + 1);
        pos += 9;
        if (length > (uint64_t)(n - pos))
            goto unusable;
        Py_ssize_t end = pos + (Py_ssize_t)length;
        if (opcode == 0x05) { /* message */
            if (length < 22)
                goto unusable;
            PyObject *channel = PyLong_FromLong((long)((unsigned)b[pos] | (unsigned)b[pos + 1] << 8));
            if (channel == NULL)
                goto error;
            PyObject *kind_obj = PyDict_GetItemWithError(kinds, channel); /* borrowed */
            Py_DECREF(channel);
            if (kind_obj == NULL) {
                if (PyErr_Occurred())
                    goto error;
            } else {
                long kind = PyLong_AsLong(kind_obj);
                if (kind == -1 && PyErr_Occurred())
                    goto error;
                if (kind < 0 || kind > 2) {
                    PyErr_SetString(PyExc_ValueError, "kinds: 0, 1 or 2");
                    goto error;
                }
                PyObject *event = message_event(b, pos + 22, end, (int)kind, classes, nan_value);
                if (event == NULL)
                    goto error;
                if (event == Py_None)
                    goto unusable;
                PyObject *log_time = PyLong_FromUnsignedLongLong(u64_at(b + pos + 6));
                PyObject *item = log_time == NULL ? NULL : PyTuple_Pack(2, log_time, event);
                Py_XDECREF(log_time);
                Py_DECREF(event);
                if (item == NULL)
                    goto error;
                int appended = PyList_Append(out, item);
                Py_DECREF(item);
                if (appended < 0)
                    goto error;
            }
        } else if (opcode == 0x04 || opcode == 0x03) { /* channel, schema: cdr_inputs' checks */
            PyObject *r = PyObject_CallFunction(opcode == 0x04 ? args[4] : args[5], "Onn", records, pos, end);
            if (r == NULL)
                goto error;
            Py_DECREF(r);
        }
        pos = end;
    }
    return out;
unusable:
    Py_DECREF(out);
    Py_RETURN_NONE;
error:
    Py_DECREF(out);
    return NULL;
}

static PyMethodDef kernel_methods[] = {
    {"chunk_events", (PyCFunction)(void (*)(void))kernel_chunk_events, METH_FASTCALL,
     "chunk_events(records, kinds, classes, nan, check_channel, check_schema) -> [(log time, event)] or None: "
     "cdr_inputs._chunk_events on a chunk's records (None: not for the fast path)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef kernel_module = {
    PyModuleDef_HEAD_INIT, "_kernel",
    "The ingest's compiled kernel: map matching in the window (see offline.py), the input messages of a bag's chunk "
    "(see cdr_inputs.py).",
    -1, kernel_methods, NULL, NULL, NULL, NULL,
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
