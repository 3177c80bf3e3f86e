/* train_calib.estimation._ukf_kernel: the UKF stage's hot paths in C, operation for operation as the Python.
 *
 * common_step(est, m, dt, a_obs, rs, rv) -> (effort, input effort, nis) or None
 *   ukf_fast.common_step_python in C: the published filter's common step (computed effort, r a consider parameter,
 *   the Euler rule, one filter, a position that passes the gate, a finite update needing no projection, a
 *   covariance that factors) committed to the estimator ``est`` (a ResistanceEstimator) for the StepInput ``m``;
 *   None, with ``est`` untouched, whenever the step leaves the common case (the Python chain then takes it).
 *
 * coast_candidates(t, v, g, run, power, by_speed, by_power, params) -> bool
 *   coast_regression.candidate_steps_python's two boolean arrays (local_slopes included) written into the
 *   preallocated by_speed and by_power (n bytes each); t, v, g float64, run int64, power int8 or None, all
 *   C-contiguous. params (floats): window, span (min(0.8 W, W - 1.5 period)), prior r0 r1 r2, ratio_min,
 *   ratio_max, hold_sigmas, sigma_v, min_speed, power_decides (0/1), power_ratio (1.6 ratio_max), joint_gap
 *   (min(max_gap, 2.5 period)). False (the arrays meaningless) when the keys run * 1e7 + (t - t0) are not
 *   sorted: the Python path then (numpy's searchsorted on an unsorted array is its own algorithm's answer).
 *   With two more float64 arrays (n each), local_slopes' slopes and 1 / sqrt(Sxx) are copied there (tests).
 *
 * Floats equal the Python's bit for bit: the same operations in the same order (the additions of the zero terms
 * included: they turn -0.0 into 0.0), no fused multiply-add (setup.py: -ffp-contract=off), libm's sqrt where
 * Python's math.sqrt and numpy's np.sqrt are (both correctly rounded), numpy's searchsorted's own binary search.
 * Agreement with the Python: test/estimation/test_ukf_kernel.py. Without a C compiler the package runs the
 * Python paths (ukf_fast.KERNEL_AVAILABLE is then False).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

/* interned attribute names */
static PyObject *s_h, *s_x, *s_P, *s_L, *s_m, *s_q_sv, *s_zv_prev, *s_g_prev, *s_c, *s_c2, *s_ic, *s_beta_alpha,
    *s_qa, *s_use_q_gain, *s_qr, *s_gate_accel, *s_position_gate, *s_last_effort, *s_last_accel, *s_last_input,
    *s_gated_since, *s_gated_count, *s_relocked, *s_v, *s_s, *s_s_measured;
static PyObject *zero_int;

/* getattr as a double (floats and ints as Python converts them); -1 on error */
static int attr_double(PyObject *obj, PyObject *name, double *out) {
    PyObject *value = PyObject_GetAttr(obj, name);
    if (value == NULL)
        return -1;
    double d = PyFloat_AsDouble(value);
    Py_DECREF(value);
    if (d == -1.0 && PyErr_Occurred())
        return -1;
    *out = d;
    return 0;
}

/* getattr as a truth value; -1 on error */
static int attr_truth(PyObject *obj, PyObject *name) {
    PyObject *value = PyObject_GetAttr(obj, name);
    if (value == NULL)
        return -1;
    int truth = PyObject_IsTrue(value);
    Py_DECREF(value);
    return truth;
}

/* the k doubles of a sequence attribute (a tuple or a list of length k); -1 on error */
static int attr_doubles(PyObject *obj, PyObject *name, double *out, Py_ssize_t k) {
    PyObject *value = PyObject_GetAttr(obj, name);
    if (value == NULL)
        return -1;
    PyObject *seq = PySequence_Fast(value, "expected a sequence");
    Py_DECREF(value);
    if (seq == NULL)
        return -1;
    if (PySequence_Fast_GET_SIZE(seq) != k) {
        Py_DECREF(seq);
        PyErr_Format(PyExc_ValueError, "expected %zd values", k);
        return -1;
    }
    PyObject **items = PySequence_Fast_ITEMS(seq);
    for (Py_ssize_t i = 0; i < k; i++) {
        double d = PyFloat_AsDouble(items[i]);
        if (d == -1.0 && PyErr_Occurred()) {
            Py_DECREF(seq);
            return -1;
        }
        out[i] = d;
    }
    Py_DECREF(seq);
    return 0;
}

static PyObject *float_tuple(const double *values, Py_ssize_t k) {
    PyObject *t = PyTuple_New(k);
    if (t == NULL)
        return NULL;
    for (Py_ssize_t i = 0; i < k; i++) {
        PyObject *f = PyFloat_FromDouble(values[i]);
        if (f == NULL) {
            Py_DECREF(t);
            return NULL;
        }
        PyTuple_SET_ITEM(t, i, f);
    }
    return t;
}

/* covariance.cholesky: the packed lower factor of the packed matrix p, 0 when it is not positive definite */
static int cholesky(const double *p, double *l) {
    double p00 = p[0], p01 = p[1], p02 = p[2], p03 = p[3], p04 = p[4], p11 = p[5], p12 = p[6], p13 = p[7],
           p14 = p[8], p22 = p[9], p23 = p[10], p24 = p[11], p33 = p[12], p34 = p[13], p44 = p[14];
    if (!(p00 > 0.0))
        return 0;
    double l00 = sqrt(p00);
    double l10 = p01 / l00;
    double l20 = p02 / l00;
    double l30 = p03 / l00;
    double l40 = p04 / l00;
    double d = p11 - l10 * l10;
    if (!(d > 0.0))
        return 0;
    double l11 = sqrt(d);
    double l21 = (p12 - l20 * l10) / l11;
    double l31 = (p13 - l30 * l10) / l11;
    double l41 = (p14 - l40 * l10) / l11;
    d = p22 - l20 * l20 - l21 * l21;
    if (!(d > 0.0))
        return 0;
    double l22 = sqrt(d);
    double l32 = (p23 - l30 * l20 - l31 * l21) / l22;
    double l42 = (p24 - l40 * l20 - l41 * l21) / l22;
    d = p33 - l30 * l30 - l31 * l31 - l32 * l32;
    if (!(d > 0.0))
        return 0;
    double l33 = sqrt(d);
    double l43 = (p34 - l40 * l30 - l41 * l31 - l42 * l32) / l33;
    d = p44 - l40 * l40 - l41 * l41 - l42 * l42 - l43 * l43;
    if (!(d > 0.0))
        return 0;
    double l44 = sqrt(d);
    l[0] = l00, l[1] = l10, l[2] = l20, l[3] = l30, l[4] = l40, l[5] = l11, l[6] = l21, l[7] = l31, l[8] = l41;
    l[9] = l22, l[10] = l32, l[11] = l42, l[12] = l33, l[13] = l43, l[14] = l44;
    double total = 0.0; /* math.isfinite(sum(out)): Python's sum, from 0, in order */
    for (int i = 0; i < 15; i++)
        total += l[i];
    return isfinite(total) ? 1 : 0;
}

/* ---- common_step ----------------------------------------------------------------------------------------- */

static PyObject *common_step(PyObject *Py_UNUSED(module), PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "common_step(est, m, dt, a_obs, rs, rv)");
        return NULL;
    }
    PyObject *est = args[0], *m = args[1];
    double dt = PyFloat_AsDouble(args[2]);
    double a_obs = PyFloat_AsDouble(args[3]);
    double rs = PyFloat_AsDouble(args[4]);
    double rv = PyFloat_AsDouble(args[5]);
    if (PyErr_Occurred())
        return NULL;
    int s_measured = attr_truth(m, s_s_measured);
    if (s_measured < 0)
        return NULL;
    if (!s_measured)
        Py_RETURN_NONE;
    double zv, zs;
    if (attr_double(m, s_v, &zv) || attr_double(m, s_s, &zs))
        return NULL;
    PyObject *h = PyObject_GetAttr(est, s_h);
    if (h == NULL)
        return NULL;
    PyObject *result = NULL, *xlist = PyObject_GetAttr(h, s_x);
    if (xlist == NULL)
        goto done;
    if (!PyList_CheckExact(xlist) || PyList_GET_SIZE(xlist) != 5) {
        PyErr_SetString(PyExc_TypeError, "common_step: the filter's x must be a list of 5");
        goto done;
    }
    double x[5], pp[15], lf[15];
    for (int i = 0; i < 5; i++) {
        x[i] = PyFloat_AsDouble(PyList_GET_ITEM(xlist, i));
        if (x[i] == -1.0 && PyErr_Occurred())
            goto done;
    }
    double zv_prev, g_prev, c, c2, ic, beta_alpha, qa, qr[3], gate_accel, position_gate;
    if (attr_double(est, s_zv_prev, &zv_prev) || attr_double(est, s_g_prev, &g_prev))
        goto done;
    /* -- _predict_published: the effort computed from the speed change (Euler: r at the filtered speed) */
    double s = x[0], v = x[1], r0 = x[2], r1 = x[3], r2 = x[4];
    double dz = zv - zv_prev;
    double r_ref = r0 + (r1 + r2 * v) * v; /* running_resistance(r0, r1, r2, v) */
    double effort = a_obs + r_ref + g_prev;
    double u = dz / dt + r_ref + g_prev;
    if (!isfinite(effort + a_obs + u)) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    if (attr_doubles(h, s_L, lf, 15) || attr_doubles(h, s_P, pp, 15))
        goto done;
    if (attr_double(est, s_c, &c) || attr_double(est, s_c2, &c2) || attr_double(est, s_ic, &ic) ||
        attr_double(est, s_beta_alpha, &beta_alpha) || attr_double(est, s_qa, &qa) ||
        attr_doubles(est, s_qr, qr, 3) || attr_double(est, s_gate_accel, &gate_accel) ||
        attr_double(est, s_position_gate, &position_gate))
        goto done;
    /* -- _predict, decoupled: only the speed components of the sigma directions move a */
    double p00 = pp[0], p01 = pp[1], p02 = pp[2], p03 = pp[3], p04 = pp[4], p11 = pp[5], p12 = pp[6],
           p13 = pp[7], p14 = pp[8], p22 = pp[9], p23 = pp[10], p24 = pp[11], p33 = pp[12], p34 = pp[13],
           p44 = pp[14];
    double hh = 0.5 * dt;
    double a0 = (u - g_prev) - r0 - (r1 + r2 * v) * v; /* _mean_acceleration (Euler) */
    double two_v = 2.0 * v;
    double l00 = lf[0], l10 = lf[1], l20 = lf[2], l30 = lf[3], l40 = lf[4], l11 = lf[5], l21 = lf[6], l31 = lf[7],
           l41 = lf[8], l22 = lf[9], l32 = lf[10], l42 = lf[11], l33 = lf[12], l43 = lf[13], l44 = lf[14];
    double dv = c * l10; /* _speed_directions (Euler) */
    double ap = -((r1 + r2 * (two_v + dv)) * dv), am = -((r1 + r2 * (two_v + -dv)) * -dv);
    double o0 = 0.5 * (ap - am), e0 = 0.5 * (ap + am);
    dv = c * l11;
    ap = -((r1 + r2 * (two_v + dv)) * dv), am = -((r1 + r2 * (two_v + -dv)) * -dv);
    double o1 = 0.5 * (ap - am), e1 = 0.5 * (ap + am);
    /* the zero terms of the decoupled directions, added as the Python adds them (without -ffast-math the compiler
     * keeps every operation that can change a value: x + 0.0 turns -0.0 into 0.0, x * 0.0 of inf is NaN) */
    const double zero = 0.0;
    double o2 = zero, e2 = zero, o3 = zero, e3 = zero, o4 = zero, e4 = zero;
    double big_e = (e0 + e1 + e2 + e3 + e4) / c2;
    double q = beta_alpha * big_e * big_e +
               (o0 * o0 + o1 * o1 + o2 * o2 + o3 * o3 + o4 * o4 + e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3 + e4 * e4) / c2;
    double m0 = l00 * o0 * ic;
    double m1 = (l10 * o0 + l11 * o1) * ic;
    double m2 = (l20 * o0 + l21 * o1 + l22 * o2) * ic;
    double m3 = (l30 * o0 + l31 * o1 + l32 * o2 + l33 * o3) * ic;
    double m4 = (l40 * o0 + l41 * o1 + l42 * o2 + l43 * o3 + l44 * o4) * ic;
    double n02 = p02 + dt * p12, n03 = p03 + dt * p13, n04 = p04 + dt * p14;
    /* _propagate_sv, grouped */
    double abar = a0 + big_e;
    double b0 = 0.5 * dt * dt;
    double b1 = dt;
    double am0 = m0 + dt * m1;
    double xs = s + dt * v + b0 * abar;
    double xv = v + dt * abar;
    double n01 = p01 + dt * p11;
    double base = p00 + dt * (p01 + n01);
    double n00 = base + (2.0 * am0 * b0 + q * b0 * b0);
    n01 += am0 * b1 + b0 * m1 + q * b0 * b1;
    double n11 = p11 + 2.0 * m1 * b1 + q * b1 * b1;
    double qs = 0.0, qsv = 0.0, qv = 0.0; /* the (s, v) process noise left out of the gain (f.q_sv) */
    if (qa > 0.0) {
        double qs_ = qa * b0 * b0, qsv_ = qa * b0 * b1, qv_ = qa * b1 * b1;
        n00 += qs_;
        n01 += qsv_;
        n11 += qv_;
        int use_q_gain = attr_truth(est, s_use_q_gain);
        if (use_q_gain < 0)
            goto done;
        if (!use_q_gain)
            qs = qs_, qsv = qsv_, qv = qv_;
    }
    b0 = hh * dt;
    p02 = n02 + b0 * m2, p03 = n03 + b0 * m3, p04 = n04 + b0 * m4;
    p12 = p12 + dt * m2, p13 = p13 + dt * m3, p14 = p14 + dt * m4;
    p22 = p22 + qr[0] * dt, p33 = p33 + qr[1] * dt, p44 = p44 + qr[2] * dt;
    /* -- _gate_position: the position passes the gate */
    double nu = zs - xs;
    double model = gate_accel * 0.5 * dt * dt;
    double var = n00 + rs + model * model;
    if (!(nu * nu <= position_gate * var)) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    /* -- _update with s and v measured, r a consider parameter (its gain zero) */
    double c00 = n00 - qs, c01 = n01 - qsv, c11 = n11 - qv;
    double nu1 = zv - xv;
    double nu0 = zs - xs;
    double s00 = c00 + rs, s11 = c11 + rv;
    double det = s00 * s11 - c01 * c01;
    if (!(det > 0.0)) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    double i00 = s11 / det, i01 = -c01 / det, i11 = s00 / det;
    double k00 = c00 * i00 + c01 * i01, k01 = c00 * i01 + c01 * i11;
    double k10 = c01 * i00 + c11 * i01, k11 = c01 * i01 + c11 * i11;
    xs += k00 * nu0 + k01 * nu1;
    xv += k10 * nu0 + k11 * nu1;
    double nis = nu0 * nu0 * i00 + 2.0 * nu0 * nu1 * i01 + nu1 * nu1 * i11;
    double k20 = zero, k21 = zero, k30 = zero, k31 = zero, k40 = zero, k41 = zero;
    r0 += k20 * nu0 + k21 * nu1;
    r1 += k30 * nu0 + k31 * nu1;
    r2 += k40 * nu0 + k41 * nu1;
    double P[15] = {
        n00 - (k00 * c00 + k01 * c01), n01 - (k00 * c01 + k01 * c11),
        p02 - (k00 * p02 + k01 * p12), p03 - (k00 * p03 + k01 * p13), p04 - (k00 * p04 + k01 * p14),
        n11 - (k10 * c01 + k11 * c11),
        p12 - (k10 * p02 + k11 * p12), p13 - (k10 * p03 + k11 * p13), p14 - (k10 * p04 + k11 * p14),
        p22 - (k20 * p02 + k21 * p12), p23 - (k20 * p03 + k21 * p13), p24 - (k20 * p04 + k21 * p14),
        p33 - (k30 * p03 + k31 * p13), p34 - (k30 * p04 + k31 * p14),
        p44 - (k40 * p04 + k41 * p14),
    };
    /* -- _safeguard: finite, nothing to project, the covariance factors */
    double new_x[5] = {xs, xv, r0, r1, r2};
    double sum_x = 0.0, sum_p = 0.0; /* math.isfinite(sum(new_x) + sum(P) + nis): Python's sums, in order */
    for (int i = 0; i < 5; i++)
        sum_x += new_x[i];
    for (int i = 0; i < 15; i++)
        sum_p += P[i];
    if (!isfinite(sum_x + sum_p + nis) || xv < 0.0 || r0 < 0.0 || r1 < 0.0 || r2 < 0.0) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    double chol[15];
    if (!cholesky(P, chol)) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    /* -- commit: what the chain leaves in the estimator (every object made before the first assignment) */
    double mm[5] = {m0, m1, m2, m3, m4}, qsv3[3] = {qs, qsv, qv};
    PyObject *xf[5] = {NULL, NULL, NULL, NULL, NULL};
    PyObject *tp = float_tuple(P, 15), *tl = float_tuple(chol, 15), *tm = float_tuple(mm, 5);
    PyObject *tq = float_tuple(qsv3, 3), *fe = PyFloat_FromDouble(effort), *fa = PyFloat_FromDouble(a_obs);
    PyObject *fu = PyFloat_FromDouble(u), *fn = PyFloat_FromDouble(nis);
    int ok = tp && tl && tm && tq && fe && fa && fu && fn;
    for (int i = 0; i < 5 && ok; i++)
        ok = (xf[i] = PyFloat_FromDouble(new_x[i])) != NULL;
    if (ok) {
        for (int i = 0; i < 5; i++) {
            PyList_SetItem(xlist, i, xf[i]); /* steals the reference */
            xf[i] = NULL;
        }
        ok = !(PyObject_SetAttr(h, s_P, tp) || PyObject_SetAttr(h, s_L, tl) || PyObject_SetAttr(h, s_m, tm) ||
               PyObject_SetAttr(h, s_q_sv, tq) || PyObject_SetAttr(est, s_last_effort, fe) ||
               PyObject_SetAttr(est, s_last_accel, fa) || PyObject_SetAttr(est, s_last_input, fu) ||
               PyObject_SetAttr(est, s_gated_since, Py_None) || PyObject_SetAttr(est, s_gated_count, zero_int) ||
               PyObject_SetAttr(est, s_relocked, Py_False));
    }
    if (ok)
        result = PyTuple_Pack(3, fe, fu, fn);
    for (int i = 0; i < 5; i++)
        Py_XDECREF(xf[i]);
    Py_XDECREF(tp);
    Py_XDECREF(tl);
    Py_XDECREF(tm);
    Py_XDECREF(tq);
    Py_XDECREF(fe);
    Py_XDECREF(fa);
    Py_XDECREF(fu);
    Py_XDECREF(fn);
done:
    Py_XDECREF(xlist);
    Py_DECREF(h);
    return result;
}

/* ---- coast_candidates --------------------------------------------------------------------------------------- */

/* numpy's npy_binsearch (npysort/binsearch.cpp) for float64 keys and array: side left (cmp a < b) or right
 * (cmp a <= b), the previous key's result narrowing the next search as numpy does; NaN sorts last (numpy's
 * Tag::less). On a sorted array every binary search gives the same (unique) indices. */
static inline int less_nan(double a, double b) { return a < b || (b != b && a == a); }

static void searchsorted(const double *arr, Py_ssize_t n, const double *keys, Py_ssize_t nk, int right,
                         Py_ssize_t *out) {
    Py_ssize_t min_idx = 0, max_idx = n;
    if (nk == 0)
        return;
    double last = keys[0];
    for (Py_ssize_t k = 0; k < nk; k++) {
        double key = keys[k];
        int up = right ? !less_nan(key, last) : less_nan(last, key); /* cmp(last_key_val, key_val) */
        if (up)
            max_idx = n;
        else {
            min_idx = 0;
            max_idx = (max_idx < n) ? (max_idx + 1) : n;
        }
        last = key;
        while (min_idx < max_idx) {
            Py_ssize_t mid = min_idx + ((max_idx - min_idx) >> 1);
            double mid_val = arr[mid];
            if (right ? !less_nan(key, mid_val) : less_nan(mid_val, key))
                min_idx = mid + 1;
            else
                max_idx = mid;
        }
        out[k] = min_idx;
    }
}

static int get_buffer(PyObject *obj, Py_buffer *view, Py_ssize_t n, Py_ssize_t itemsize, int writable,
                      const char *what) {
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | (writable ? PyBUF_WRITABLE : 0)) < 0)
        return -1;
    if (view->len != n * itemsize || view->itemsize != itemsize) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_ValueError, "coast_candidates: %s has the wrong size", what);
        return -1;
    }
    return 0;
}

static PyObject *coast_candidates(PyObject *Py_UNUSED(module), PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 8 && nargs != 10) {
        PyErr_SetString(PyExc_TypeError,
                        "coast_candidates(t, v, g, run, power, by_speed, by_power, params[, slopes, inv_se])");
        return NULL;
    }
    double p[13];
    PyObject *params = PySequence_Fast(args[7], "params must be a sequence");
    if (params == NULL)
        return NULL;
    if (PySequence_Fast_GET_SIZE(params) != 13) {
        Py_DECREF(params);
        PyErr_SetString(PyExc_ValueError, "coast_candidates: 13 params");
        return NULL;
    }
    for (int i = 0; i < 13; i++)
        p[i] = PyFloat_AsDouble(PySequence_Fast_ITEMS(params)[i]);
    Py_DECREF(params);
    if (PyErr_Occurred())
        return NULL;
    double window = p[0], span = p[1], pr0 = p[2], pr1 = p[3], pr2 = p[4], ratio_min = p[5], ratio_max = p[6];
    double hold_sigmas = p[7], sigma_v = p[8], min_speed = p[9], power_ratio = p[11], joint_gap = p[12];
    int power_decides = p[10] != 0.0;
    Py_buffer bt, bv, bg, brun, bpow, bspeed, bpower;
    Py_ssize_t n;
    if (PyObject_GetBuffer(args[0], &bt, PyBUF_C_CONTIGUOUS) < 0)
        return NULL;
    n = bt.len / (Py_ssize_t)sizeof(double);
    if (bt.itemsize != sizeof(double)) {
        PyBuffer_Release(&bt);
        PyErr_SetString(PyExc_ValueError, "coast_candidates: t must be float64");
        return NULL;
    }
    int have_power = args[4] != Py_None;
    PyObject *result = NULL;
    Py_ssize_t *lo = NULL, *hi = NULL;
    double *work = NULL;
    if (get_buffer(args[1], &bv, n, 8, 0, "v"))
        goto release_t;
    if (get_buffer(args[2], &bg, n, 8, 0, "g"))
        goto release_v;
    if (get_buffer(args[3], &brun, n, 8, 0, "run"))
        goto release_g;
    if (have_power && get_buffer(args[4], &bpow, n, 1, 0, "power"))
        goto release_run;
    if (get_buffer(args[5], &bspeed, n, 1, 1, "by_speed"))
        goto release_pow;
    if (get_buffer(args[6], &bpower, n, 1, 1, "by_power"))
        goto release_speed;
    const double *t = bt.buf, *v = bv.buf, *g = bg.buf;
    const int64_t *run = brun.buf;
    const int8_t *power = have_power ? bpow.buf : NULL;
    unsigned char *step_speed = bspeed.buf, *step_power = bpower.buf;
    memset(step_speed, 0, (size_t)n);
    memset(step_power, 0, (size_t)n);
    if (n == 0) {
        result = Py_NewRef(Py_True);
        goto release_all;
    }
    /* per sample: tc, key, lo/hi key, the prefix sums (4 columns), a, se, flags */
    work = PyMem_Malloc((size_t)(n * 5 + (n + 1) * 4) * sizeof(double));
    lo = PyMem_Malloc((size_t)n * sizeof(Py_ssize_t));
    hi = PyMem_Malloc((size_t)n * sizeof(Py_ssize_t));
    if (work == NULL || lo == NULL || hi == NULL) {
        PyErr_NoMemory();
        goto release_all;
    }
    double *tc = work, *key = work + n, *bound = work + 2 * n, *a = work + 3 * n, *inv_se = work + 4 * n;
    double *sums = work + 5 * n; /* (n + 1) x 4, row-major */
    /* -- local_slopes (NaN where the window holds < 3 samples or too short a span) */
    if (n < 3) {
        for (Py_ssize_t i = 0; i < n; i++)
            a[i] = inv_se[i] = NAN;
    } else {
        double t0 = t[0];
        for (Py_ssize_t i = 0; i < n; i++) {
            tc[i] = t[i] - t0;
            key[i] = (double)run[i] * 1e7 + tc[i];
            if (i && !(key[i] >= key[i - 1])) { /* keys not sorted (or NaN): the numpy path decides */
                result = Py_NewRef(Py_False);
                goto release_all;
            }
        }
        for (Py_ssize_t i = 0; i < n; i++)
            bound[i] = key[i] - 0.5 * window - 1e-6;
        searchsorted(key, n, bound, n, 0, lo);
        for (Py_ssize_t i = 0; i < n; i++)
            bound[i] = key[i] + 0.5 * window + 1e-6;
        searchsorted(key, n, bound, n, 1, hi);
        double c0 = 0.0, c1 = 0.0, c2 = 0.0, c3 = 0.0; /* cumsum from the row of zeros, column by column */
        sums[0] = sums[1] = sums[2] = sums[3] = 0.0;
        for (Py_ssize_t i = 0; i < n; i++) {
            c0 = c0 + tc[i];
            c1 = c1 + tc[i] * tc[i];
            c2 = c2 + v[i];
            c3 = c3 + tc[i] * v[i];
            double *row = sums + 4 * (i + 1);
            row[0] = c0, row[1] = c1, row[2] = c2, row[3] = c3;
        }
        for (Py_ssize_t i = 0; i < n; i++) {
            /* sorted keys: lo <= i < hi (searchsorted right), so the window holds sample i and no index wraps */
            Py_ssize_t l = lo[i], h = hi[i] - 1;
            const double *rh = sums + 4 * (h + 1), *rl = sums + 4 * l;
            double st = rh[0] - rl[0], stt = rh[1] - rl[1], sv = rh[2] - rl[2], stv = rh[3] - rl[3];
            double cnt = (double)(h - l + 1);
            double sxx = stt - st * st / (cnt >= 1.0 ? cnt : 1.0);
            int ok = (cnt >= 3) && (tc[h] - tc[l] >= span) && (sxx > 0.0);
            if (ok) {
                a[i] = (stv - st * sv / cnt) / sxx;
                inv_se[i] = 1.0 / sqrt(sxx);
            } else
                a[i] = inv_se[i] = NAN;
        }
    }
    /* -- candidate_steps */
    for (Py_ssize_t i = 0; i < n; i++) {
        double vi = v[i];
        double davis = pr0 + (pr1 + pr2 * vi) * vi;
        double ratio = -(a[i] + g[i]) / (isnan(davis) ? davis : (davis >= 1e-6 ? davis : 1e-6));
        int moving = vi >= min_speed;
        int speed = (ratio >= ratio_min) && (ratio <= ratio_max) && (fabs(a[i]) >= hold_sigmas * inv_se[i] * sigma_v) &&
                    moving && isfinite(a[i]);
        int by_power = 0;
        if (have_power && power_decides) {
            int known = power[i] != 0;
            speed = speed && !known;
            by_power = (power[i] == 1) && moving && !(ratio > power_ratio);
        }
        bound[i] = speed ? 1.0 : 0.0; /* candidates by speed */
        key[i] = by_power ? 1.0 : 0.0; /* candidates by power */
    }
    if (nargs == 10) { /* local_slopes' two arrays too (the tests compare them) */
        Py_buffer bout;
        for (int k = 0; k < 2; k++) {
            if (get_buffer(args[8 + k], &bout, n, 8, 1, k ? "inv_se" : "slopes"))
                goto release_all;
            memcpy(bout.buf, k ? inv_se : a, (size_t)n * sizeof(double));
            PyBuffer_Release(&bout);
        }
    }
    int power_steps = have_power && power_decides;
    for (Py_ssize_t i = 1; i < n; i++) {
        int joint = run[i] == run[i - 1] && t[i] - t[i - 1] <= joint_gap;
        step_speed[i] = bound[i] != 0.0 && bound[i - 1] != 0.0 && joint;
        step_power[i] = power_steps && key[i] != 0.0 && key[i - 1] != 0.0 && joint;
    }
    result = Py_NewRef(Py_True);
release_all:
    PyMem_Free(work);
    PyMem_Free(lo);
    PyMem_Free(hi);
    PyBuffer_Release(&bpower);
release_speed:
    PyBuffer_Release(&bspeed);
release_pow:
    if (have_power)
        PyBuffer_Release(&bpow);
release_run:
    PyBuffer_Release(&brun);
release_g:
    PyBuffer_Release(&bg);
release_v:
    PyBuffer_Release(&bv);
release_t:
    PyBuffer_Release(&bt);
    return result;
}

/* ---- module ---------------------------------------------------------------------------------------------- */

static PyMethodDef methods[] = {
    {"common_step", (PyCFunction)(void (*)(void))common_step, METH_FASTCALL,
     "common_step(est, m, dt, a_obs, rs, rv) -> (effort, input effort, nis) or None: ukf_fast.common_step_python."},
    {"coast_candidates", (PyCFunction)(void (*)(void))coast_candidates, METH_FASTCALL,
     "coast_candidates(t, v, g, run, power, by_speed, by_power, params): coast_regression.candidate_steps_python."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_ukf_kernel", "The UKF stage's C kernel.", -1, methods,
                                    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__ukf_kernel(void) {
#define INTERN(var, text)                                                                                        \
    if ((var = PyUnicode_InternFromString(text)) == NULL)                                                        \
        return NULL;
    INTERN(s_h, "_h");
    INTERN(s_x, "x");
    INTERN(s_P, "P");
    INTERN(s_L, "L");
    INTERN(s_m, "m");
    INTERN(s_q_sv, "q_sv");
    INTERN(s_zv_prev, "_zv_prev");
    INTERN(s_g_prev, "_g_prev");
    INTERN(s_c, "_c");
    INTERN(s_c2, "_c2");
    INTERN(s_ic, "_ic");
    INTERN(s_beta_alpha, "_beta_alpha");
    INTERN(s_qa, "_qa");
    INTERN(s_use_q_gain, "_use_q_gain");
    INTERN(s_qr, "_qr");
    INTERN(s_gate_accel, "_gate_accel");
    INTERN(s_position_gate, "_position_gate");
    INTERN(s_last_effort, "_last_effort");
    INTERN(s_last_accel, "_last_accel");
    INTERN(s_last_input, "_last_input");
    INTERN(s_gated_since, "_gated_since");
    INTERN(s_gated_count, "_gated_count");
    INTERN(s_relocked, "_relocked");
    INTERN(s_v, "v");
    INTERN(s_s, "s");
    INTERN(s_s_measured, "s_measured");
#undef INTERN
    if ((zero_int = PyLong_FromLong(0)) == NULL)
        return NULL;
    return PyModule_Create(&module);
}
