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
 * coast_push(reg, t, v, g, tunnel, run_id, power, s, gamma, s_var, v_var) -> 0, 1 or 2
 *   CoastRegression.push_python on the regression ``reg``'s own lists and deques up to the detection: 0 the push
 *   is over (push returns False), 1 push returns reg._detect(), 2 (nothing changed) a stamp not after the last one,
 *   left to push_python (a repeated stamp or a clock reset).
 *
 * step_input(StepInput, m) -> StepInput
 *   ukf.StepInput.from_measurement: the Measurement's fields as int, float and bool, in StepInput's order.
 *
 * process_common(est, m) -> StepResult or None
 *   ResistanceEstimator.process of the common sample (the input used as it is, the run going on, 0 < dt <= max_dt,
 *   the common step configured and the kernel's): the coast regression's push, the speed slope, the common step,
 *   the NIS window and the StepResult as process -> _step -> _common_result make them, calling back into the
 *   estimator where they do something else (_power_state with a power measurement, the coast regression's
 *   _detect / push_python / _take_coast_resistance, _step_chain when the common step declines,
 *   _nis_inconsistent). None, with nothing changed, for any other sample: process then runs in Python.
 *   configure(...) first gives it StepInput, StepResult and the input limits (ukf_types.py).
 *
 * slope_push(slope, t, v) -> slope
 *   effort.SpeedSlope.push_python on the SpeedSlope ``slope``'s own deque and running sums (its _refresh called
 *   every _REFRESH pushes as the Python does).
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

/* ---- coast_push ----------------------------------------------------------------------------------------------- */

static PyObject *s_t_, *s_v_, *s_g_, *s_tun_, *s_run_, *s_power_, *s_s_, *s_gamma_, *s_s_var_, *s_v_var_, *s_d2_,
    *s_d3_, *s_grade_errors_, *s_quantum_, *s_d2_seen_, *s_prior_floats_, *s_grade_seen_, *s_period_,
    *s_refresh_wait_, *s_REFRESH, *s_REFRESH_PERIODS, *s_v_max_, *s_v_min_, *s_moving_before_, *s_moved_,
    *s_last_detect_, *s_open_, *s_append, *float_zero;

#define PUSH_IDLE 0   /* nothing to detect: push returns False */
#define PUSH_DETECT 1 /* push returns self._detect() */
#define PUSH_PYTHON 2 /* a case left to the Python (a stamp not after the last one): nothing was changed */

static int as_double(PyObject *obj, double *out) {
    double d = PyFloat_AsDouble(obj);
    if (d == -1.0 && PyErr_Occurred())
        return -1;
    *out = d;
    return 0;
}

static int call_append(PyObject *container, PyObject *item) {
    if (PyList_CheckExact(container))
        return PyList_Append(container, item);
    PyObject *r = PyObject_CallMethodOneArg(container, s_append, item);
    if (r == NULL)
        return -1;
    Py_DECREF(r);
    return 0;
}

static int append_double(PyObject *container, double value) {
    PyObject *f = PyFloat_FromDouble(value);
    if (f == NULL)
        return -1;
    int rc = call_append(container, f);
    Py_DECREF(f);
    return rc;
}

static int set_double(PyObject *obj, PyObject *name, double value) {
    PyObject *f = PyFloat_FromDouble(value);
    if (f == NULL)
        return -1;
    int rc = PyObject_SetAttr(obj, name, f);
    Py_DECREF(f);
    return rc;
}

static int add_one(PyObject *obj, PyObject *name) {
    PyObject *count = PyObject_GetAttr(obj, name);
    if (count == NULL)
        return -1;
    PyObject *one = PyLong_FromLong(1);
    PyObject *next = one ? PyNumber_Add(count, one) : NULL;
    Py_DECREF(count);
    Py_XDECREF(one);
    if (next == NULL)
        return -1;
    int rc = PyObject_SetAttr(obj, name, next);
    Py_DECREF(next);
    return rc;
}

static PyObject *coast_push(PyObject *Py_UNUSED(module), PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 11) {
        PyErr_SetString(PyExc_TypeError, "coast_push(reg, t, v, g, tunnel, run_id, power, s, gamma, s_var, v_var)");
        return NULL;
    }
    PyObject *reg = args[0], *ot = args[1], *ov = args[2], *og = args[3], *otun = args[4], *orun = args[5];
    PyObject *opower = args[6], *os = args[7], *ogamma = args[8], *os_var = args[9], *ov_var = args[10];
    double t, v, g, tunnel, s, gamma, s_var;
    if (as_double(ot, &t) || as_double(ov, &v) || as_double(og, &g))
        return NULL;
    if (!(isfinite(t) && isfinite(v) && isfinite(g)))
        return PyLong_FromLong(PUSH_IDLE);
    enum { T, V, G, TUN, RUN, POWER, S, GAMMA, S_VAR, V_VAR, NLISTS };
    PyObject *names[NLISTS] = {s_t_, s_v_, s_g_, s_tun_, s_run_, s_power_, s_s_, s_gamma_, s_s_var_, s_v_var_};
    PyObject *lists[NLISTS] = {NULL};
    PyObject *result = NULL, *run_int = NULL, *power_int = NULL, *tun_item = NULL, *s_var_item = NULL;
    PyObject *tmp = NULL;
    int code = PUSH_IDLE;
    for (int i = 0; i < NLISTS; i++) {
        lists[i] = PyObject_GetAttr(reg, names[i]);
        if (lists[i] == NULL)
            goto done;
        if (!PyList_CheckExact(lists[i])) {
            PyErr_SetString(PyExc_TypeError, "coast_push: the buffers must be lists");
            goto done;
        }
    }
    PyObject *ts = lists[T], *vs = lists[V], *runs = lists[RUN];
    Py_ssize_t n = PyList_GET_SIZE(ts);
    if (PyList_GET_SIZE(vs) != n || PyList_GET_SIZE(runs) != n || PyList_GET_SIZE(lists[G]) != n ||
        PyList_GET_SIZE(lists[GAMMA]) != n || PyList_GET_SIZE(lists[S]) != n) {
        result = PyLong_FromLong(PUSH_PYTHON);
        goto done;
    }
    double last_t = 0.0;
    if (n) {
        if (as_double(PyList_GET_ITEM(ts, n - 1), &last_t))
            goto done;
        if (t <= last_t) { /* an older or repeated stamp, or a clock reset: the Python */
            result = PyLong_FromLong(PUSH_PYTHON);
            goto done;
        }
    }
    /* every conversion before the first change */
    if (as_double(otun, &tunnel) || as_double(os, &s) || as_double(ogamma, &gamma) || as_double(os_var, &s_var))
        goto done;
    run_int = PyNumber_Long(orun);
    power_int = run_int ? PyNumber_Long(opower) : NULL;
    if (power_int == NULL)
        goto done;
    double v_min;
    if (attr_double(reg, s_v_min_, &v_min))
        goto done;
    if (n) { /* the noise and grade-error terms of the step from the previous sample */
        double v1;
        if (as_double(PyList_GET_ITEM(vs, n - 1), &v1))
            goto done;
        int same_run = PyObject_RichCompareBool(PyList_GET_ITEM(runs, n - 1), orun, Py_EQ);
        if (same_run < 0)
            goto done;
        double dv = fabs(v - v1);
        if (dv > 1e-4) {
            double quantum;
            if (attr_double(reg, s_quantum_, &quantum))
                goto done;
            if (dv < quantum && set_double(reg, s_quantum_, dv)) /* min(quantum, dv) */
                goto done;
        }
        if (n >= 2 && v1 > 5.0 && same_run) {
            int run2 = PyObject_RichCompareBool(orun, PyList_GET_ITEM(runs, n - 2), Py_EQ);
            if (run2 < 0)
                goto done;
            if (run2) {
                double v2;
                if (as_double(PyList_GET_ITEM(vs, n - 2), &v2))
                    goto done;
                tmp = PyObject_GetAttr(reg, s_d2_);
                if (tmp == NULL || append_double(tmp, v - 2.0 * v1 + v2))
                    goto done;
                Py_CLEAR(tmp);
                if (add_one(reg, s_d2_seen_))
                    goto done;
                if (n >= 3) {
                    int run3 = PyObject_RichCompareBool(PyList_GET_ITEM(runs, n - 3), orun, Py_EQ);
                    if (run3 < 0)
                        goto done;
                    if (run3 && v2 > 5.0) {
                        double v3;
                        if (as_double(PyList_GET_ITEM(vs, n - 3), &v3))
                            goto done;
                        tmp = PyObject_GetAttr(reg, s_d3_);
                        if (tmp == NULL || append_double(tmp, v - 3.0 * v1 + 3.0 * v2 - v3))
                            goto done;
                        Py_CLEAR(tmp);
                    }
                }
            }
        }
        double gamma1;
        if (as_double(PyList_GET_ITEM(lists[GAMMA], n - 1), &gamma1))
            goto done;
        if (same_run && isfinite(gamma) && isfinite(gamma1)) {
            double s1;
            if (as_double(PyList_GET_ITEM(lists[S], n - 1), &s1))
                goto done;
            double ds = s - s1;
            if (ds > 1.0 && v >= v_min && v1 >= v_min) {
                double v_mid = 0.5 * (v + v1), r[3], g1;
                if (attr_doubles(reg, s_prior_floats_, r, 3) || as_double(PyList_GET_ITEM(lists[G], n - 1), &g1))
                    goto done;
                double exact = (gamma - gamma1) / ds;
                double ref = r[0] + (r[1] + r[2] * v_mid) * v_mid;
                double floor = 1e-6 > ref ? 1e-6 : ref; /* max(ref, 1e-6) */
                tmp = PyObject_GetAttr(reg, s_grade_errors_);
                if (tmp == NULL || append_double(tmp, fabs(exact - 0.5 * (g + g1)) / floor))
                    goto done;
                Py_CLEAR(tmp);
                if (add_one(reg, s_grade_seen_))
                    goto done;
            }
        }
        double period = t - last_t, refresh, periods;
        if (set_double(reg, s_period_, period) || attr_double(reg, s_REFRESH, &refresh) ||
            attr_double(reg, s_REFRESH_PERIODS, &periods))
            goto done;
        double wait = periods * period;
        if (set_double(reg, s_refresh_wait_, wait > refresh ? wait : refresh)) /* max(REFRESH, ...) */
            goto done;
    }
    tun_item = isfinite(tunnel) ? Py_NewRef(otun) : Py_NewRef(float_zero);
    s_var_item = isfinite(s_var) ? Py_NewRef(os_var) : Py_NewRef(float_zero);
    PyObject *items[NLISTS] = {ot, ov, og, tun_item, run_int, power_int, os, ogamma, s_var_item, ov_var};
    for (int i = 0; i < NLISTS; i++)
        if (PyList_Append(lists[i], items[i]))
            goto done;
    double v_max;
    if (attr_double(reg, s_v_max_, &v_max))
        goto done;
    if (v > v_max && PyObject_SetAttr(reg, s_v_max_, ov))
        goto done;
    int moving = v >= v_min;
    int moving_before = attr_truth(reg, s_moving_before_);
    if (moving_before < 0)
        goto done;
    int stopped = moving_before && !moving; /* the first slow sample after moving: a coast before is over */
    if (PyObject_SetAttr(reg, s_moving_before_, moving ? Py_True : Py_False))
        goto done;
    if (moving && PyObject_SetAttr(reg, s_moved_, Py_True))
        goto done;
    double last_detect, refresh_wait;
    if (attr_double(reg, s_last_detect_, &last_detect) || attr_double(reg, s_refresh_wait_, &refresh_wait))
        goto done;
    if (!stopped && t - last_detect < refresh_wait) {
        result = PyLong_FromLong(PUSH_IDLE);
        goto done;
    }
    if (PyObject_SetAttr(reg, s_last_detect_, ot))
        goto done;
    int moved = attr_truth(reg, s_moved_), open = moved < 0 ? -1 : attr_truth(reg, s_open_);
    if (open < 0)
        goto done;
    if (!moved && !open) { /* standing since the last detection: nothing can have changed */
        result = PyLong_FromLong(PUSH_IDLE);
        goto done;
    }
    if (PyObject_SetAttr(reg, s_moved_, Py_False))
        goto done;
    code = PUSH_DETECT;
    result = PyLong_FromLong(code);
done:
    for (int i = 0; i < NLISTS; i++)
        Py_XDECREF(lists[i]);
    Py_XDECREF(run_int);
    Py_XDECREF(power_int);
    Py_XDECREF(tun_item);
    Py_XDECREF(s_var_item);
    Py_XDECREF(tmp);
    return result;
}

/* ---- slope_push ------------------------------------------------------------------------------------------------ */

static PyObject *s_points_, *s_t_ref_, *s_st_, *s_sv_, *s_stt_, *s_stv_, *s_svv_, *s_count_, *s_window, *s_slope,
    *s_REFRESH_, *s_refresh_, *s_popleft;

static PyObject *slope_push(PyObject *Py_UNUSED(module), PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "slope_push(slope, t, v)");
        return NULL;
    }
    PyObject *self = args[0], *ot = args[1], *ov = args[2];
    double t, v;
    if (as_double(ot, &t) || as_double(ov, &v))
        return NULL;
    PyObject *result = NULL, *pts = PyObject_GetAttr(self, s_points_), *point = NULL, *first = NULL;
    if (pts == NULL)
        return NULL;
    Py_ssize_t n = PyObject_Length(pts);
    if (n < 0)
        goto done;
    if (n == 0 && PyObject_SetAttr(self, s_t_ref_, ot))
        goto done;
    point = PyTuple_Pack(2, ot, ov);
    if (point == NULL || call_append(pts, point))
        goto done;
    n += 1;
    double t_ref, st, sv, stt, stv, svv, window;
    if (attr_double(self, s_t_ref_, &t_ref) || attr_double(self, s_st_, &st) || attr_double(self, s_sv_, &sv) ||
        attr_double(self, s_stt_, &stt) || attr_double(self, s_stv_, &stv) || attr_double(self, s_svv_, &svv) ||
        attr_double(self, s_window, &window))
        goto done;
    double d = t - t_ref;
    /* the running sums in locals, stored once (the same additions in the same order) */
    st = st + d, sv = sv + v, stt = stt + d * d, stv = stv + d * v, svv = svv + v * v;
    double limit = t - 1.02 * window - 1e-6; /* 2 % tolerance for stamp jitter */
    while (n > 2) {
        first = PySequence_GetItem(pts, 0);
        if (first == NULL)
            goto done;
        double t0, v0;
        if (!PyTuple_Check(first) || PyTuple_GET_SIZE(first) != 2) {
            PyErr_SetString(PyExc_TypeError, "slope_push: points must be (t, v) tuples");
            goto done;
        }
        if (as_double(PyTuple_GET_ITEM(first, 0), &t0))
            goto done;
        if (!(t0 < limit))
            break;
        if (as_double(PyTuple_GET_ITEM(first, 1), &v0))
            goto done;
        Py_CLEAR(first);
        PyObject *dropped = PyObject_CallMethodNoArgs(pts, s_popleft);
        if (dropped == NULL)
            goto done;
        Py_DECREF(dropped);
        n -= 1;
        d = t0 - t_ref;
        st -= d;
        sv -= v0;
        stt -= d * d;
        stv -= d * v0;
        svv -= v0 * v0;
    }
    Py_CLEAR(first);
    if (set_double(self, s_st_, st) || set_double(self, s_sv_, sv) || set_double(self, s_stt_, stt) ||
        set_double(self, s_stv_, stv) || set_double(self, s_svv_, svv) || add_one(self, s_count_))
        goto done;
    double count, refresh;
    if (attr_double(self, s_count_, &count) || attr_double(self, s_REFRESH_, &refresh))
        goto done;
    if (count >= refresh) { /* the sums recomputed from the samples (Python's _refresh) */
        PyObject *r = PyObject_CallMethodNoArgs(self, s_refresh_);
        if (r == NULL)
            goto done;
        Py_DECREF(r);
        if (attr_double(self, s_st_, &st) || attr_double(self, s_sv_, &sv) || attr_double(self, s_stt_, &stt) ||
            attr_double(self, s_stv_, &stv))
            goto done;
    }
    /* _fit */
    double slope = 0.0;
    if (n == 2) {
        PyObject *p0 = PySequence_GetItem(pts, 0), *p1 = p0 ? PySequence_GetItem(pts, 1) : NULL;
        double t0 = 0.0, v0 = 0.0, t1 = 0.0, v1 = 0.0;
        int bad = p1 == NULL || !PyTuple_Check(p0) || !PyTuple_Check(p1) || PyTuple_GET_SIZE(p0) != 2 ||
                  PyTuple_GET_SIZE(p1) != 2 || as_double(PyTuple_GET_ITEM(p0, 0), &t0) ||
                  as_double(PyTuple_GET_ITEM(p0, 1), &v0) || as_double(PyTuple_GET_ITEM(p1, 0), &t1) ||
                  as_double(PyTuple_GET_ITEM(p1, 1), &v1);
        Py_XDECREF(p0);
        Py_XDECREF(p1);
        if (bad) {
            if (!PyErr_Occurred())
                PyErr_SetString(PyExc_TypeError, "slope_push: points must be (t, v) tuples");
            goto done;
        }
        slope = t1 > t0 ? (v1 - v0) / (t1 - t0) : 0.0;
    } else if (n > 2) {
        double sxx = stt - st * st / (double)n;
        slope = sxx > 0.0 ? (stv - st * sv / (double)n) / sxx : 0.0;
    }
    PyObject *out = PyFloat_FromDouble(slope);
    if (out == NULL)
        goto done;
    if (PyObject_SetAttr(self, s_slope, out)) {
        Py_DECREF(out);
        goto done;
    }
    result = out;
done:
    Py_XDECREF(first);
    Py_XDECREF(point);
    Py_DECREF(pts);
    return result;
}

/* ---- step_input ------------------------------------------------------------------------------------------------ */

static PyObject *s_stamp_ns, *s_run_id, *s_track_force, *s_s_variance, *s_v_variance, *s_power_valid,
    *s_power_consumed, *s_power_regenerated, *s_tunnel_fraction, *s_track_force_integral;

#define STEP_FIELDS 13

static PyObject *step_input(PyObject *Py_UNUSED(module), PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 2 || !PyType_Check(args[0]) || !PyType_IsSubtype((PyTypeObject *)args[0], &PyTuple_Type)) {
        PyErr_SetString(PyExc_TypeError, "step_input(StepInput, m)");
        return NULL;
    }
    PyObject *m = args[1];
    /* StepInput's fields in order: 'i' int(), 'f' float(), 'b' bool() of the Measurement's attribute */
    PyObject *names[STEP_FIELDS] = {s_stamp_ns,      s_run_id,          s_s,           s_v,          s_track_force,
                                    s_s_measured,    s_s_variance,      s_v_variance,  s_power_valid,
                                    s_power_consumed, s_power_regenerated, s_tunnel_fraction, s_track_force_integral};
    static const char kinds[STEP_FIELDS + 1] = "iifffbffbffff";
    PyObject *items = PyTuple_New(STEP_FIELDS);
    if (items == NULL)
        return NULL;
    for (int i = 0; i < STEP_FIELDS; i++) {
        PyObject *value = PyObject_GetAttr(m, names[i]), *item = NULL;
        if (value == NULL) {
            Py_DECREF(items);
            return NULL;
        }
        if (kinds[i] == 'i')
            item = PyNumber_Long(value);
        else if (kinds[i] == 'f')
            item = PyNumber_Float(value);
        else {
            int truth = PyObject_IsTrue(value);
            item = truth < 0 ? NULL : Py_NewRef(truth ? Py_True : Py_False);
        }
        Py_DECREF(value);
        if (item == NULL) {
            Py_DECREF(items);
            return NULL;
        }
        PyTuple_SET_ITEM(items, i, item);
    }
    /* tuple.__new__(StepInput, items): what the namedtuple's own __new__ does */
    PyObject *call_args = PyTuple_Pack(1, items);
    Py_DECREF(items);
    if (call_args == NULL)
        return NULL;
    PyObject *out = PyTuple_Type.tp_new((PyTypeObject *)args[0], call_args, NULL);
    Py_DECREF(call_args);
    return out;
}

/* ---- process_common ------------------------------------------------------------------------------------------ */

static PyObject *step_input_type, *step_result_type, *health_ok, *effort_computed, *small_ints;
static double max_speed, max_track_force, max_position, max_power, variance_lo, variance_hi;
static PyObject *s_common, *s_common_step, *s_counters, *s_updates, *s_rejected, *s_run_id_, *s_last_stamp,
    *s_config, *s_max_dt, *s_use_measurement_variance, *s_rs, *s_rv, *s_coast, *s_power_state, *s_detect,
    *s_push_python, *s_take_coast_resistance, *s_slope_, *s_step_chain, *s_nis_ring, *s_nis_sum, *s_nis_dof,
    *s_nis_window, *s_nis_limit, *s_nis_inconsistent, *s_degraded_steps, *s_pw_prev;

static PyObject *configure(PyObject *Py_UNUSED(module), PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 10) {
        PyErr_SetString(PyExc_TypeError, "configure(StepInput, StepResult, MAX_SPEED, MAX_TRACK_FORCE, MAX_POSITION, "
                                         "MAX_POWER, variance_lo, variance_hi, HEALTH_OK, EFFORT_COMPUTED)");
        return NULL;
    }
    double limits[6];
    for (int i = 0; i < 6; i++)
        if (as_double(args[2 + i], &limits[i]))
            return NULL;
    Py_XSETREF(step_input_type, Py_NewRef(args[0]));
    Py_XSETREF(step_result_type, Py_NewRef(args[1]));
    Py_XSETREF(health_ok, Py_NewRef(args[8]));
    Py_XSETREF(effort_computed, Py_NewRef(args[9]));
    max_speed = limits[0], max_track_force = limits[1], max_position = limits[2], max_power = limits[3];
    variance_lo = limits[4], variance_hi = limits[5];
    Py_RETURN_NONE;
}

/* the double of item i of the StepInput tuple m; -1 on error */
static int item_double(PyObject *m, Py_ssize_t i, double *out) { return as_double(PyTuple_GET_ITEM(m, i), out); }

static PyObject *process_common(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "process_common(est, m)");
        return NULL;
    }
    PyObject *est = args[0], *m = args[1];
    if (step_input_type == NULL || (PyObject *)Py_TYPE(m) != step_input_type || PyTuple_GET_SIZE(m) != STEP_FIELDS)
        Py_RETURN_NONE;
    /* -- the conditions of the common sample, read before anything changes (None: ResistanceEstimator.process) */
    int flag = attr_truth(est, s_common);
    if (flag <= 0)
        return flag < 0 ? NULL : Py_NewRef(Py_None);
    PyObject *step_fn = PyObject_GetAttr(est, s_common_step);
    if (step_fn == NULL)
        return NULL;
    int ours = PyCFunction_Check(step_fn) && PyCFunction_GET_FUNCTION(step_fn) == (PyCFunction)(void (*)(void))common_step;
    Py_DECREF(step_fn);
    if (!ours)
        Py_RETURN_NONE;
    PyObject *o_stamp = PyTuple_GET_ITEM(m, 0), *o_run = PyTuple_GET_ITEM(m, 1), *o_s = PyTuple_GET_ITEM(m, 2);
    PyObject *o_v = PyTuple_GET_ITEM(m, 3), *o_g = PyTuple_GET_ITEM(m, 4);
    double v, g, s, s_var, v_var, pc, pr;
    if (item_double(m, 3, &v) || item_double(m, 4, &g) || item_double(m, 2, &s) || item_double(m, 6, &s_var) ||
        item_double(m, 7, &v_var) || item_double(m, 9, &pc) || item_double(m, 10, &pr))
        return NULL;
    /* _rejection: nan, negative_speed, implausible */
    if (!(isfinite(v) && isfinite(g)) || v < 0.0 || v > max_speed || fabs(g) > max_track_force)
        Py_RETURN_NONE;
    /* _repaired: the measurement used as it is */
    int power_valid = PyObject_IsTrue(PyTuple_GET_ITEM(m, 8));
    if (power_valid < 0)
        return NULL;
    if (!(fabs(s) <= max_position) || !(variance_lo <= s_var && s_var <= variance_hi) ||
        !(variance_lo <= v_var && v_var <= variance_hi) ||
        (power_valid && !(0.0 <= pc && pc <= max_power && 0.0 <= pr && pr <= max_power)))
        Py_RETURN_NONE;
    PyObject *result = NULL, *h = NULL, *x = NULL, *run_id = NULL, *last_stamp = NULL, *diff = NULL, *o_dt = NULL;
    PyObject *o_t = NULL, *config = NULL, *o_rs = NULL, *o_rv = NULL, *coast = NULL, *slope = NULL, *o_a = NULL;
    PyObject *common = NULL, *ring = NULL, *tmp = NULL, *health = NULL;
    h = PyObject_GetAttr(est, s_h);
    x = h ? PyObject_GetAttr(h, s_x) : NULL;
    run_id = x ? PyObject_GetAttr(est, s_run_id_) : NULL;
    last_stamp = run_id ? PyObject_GetAttr(est, s_last_stamp) : NULL;
    if (last_stamp == NULL)
        goto done;
    if (x == Py_None) { /* a run to start */
        result = Py_NewRef(Py_None);
        goto done;
    }
    flag = PyObject_RichCompareBool(o_run, run_id, Py_EQ);
    if (flag <= 0) { /* out of order is for a sample of the same run; another run: _start_run */
        result = flag < 0 ? NULL : Py_NewRef(Py_None);
        goto done;
    }
    flag = PyObject_RichCompareBool(o_stamp, last_stamp, Py_LT);
    if (flag) { /* out_of_order */
        result = flag < 0 ? NULL : Py_NewRef(Py_None);
        goto done;
    }
    diff = PyNumber_Subtract(o_stamp, last_stamp); /* (m.stamp_ns - self._last_stamp) * 1e-9 */
    double dt, max_dt;
    if (diff == NULL || as_double(diff, &dt))
        goto done;
    dt = dt * 1e-9;
    config = PyObject_GetAttr(est, s_config);
    if (config == NULL || attr_double(config, s_max_dt, &max_dt))
        goto done;
    if (dt > max_dt || !(dt > 0.0)) { /* a gap, or a step without time: the Python */
        result = Py_NewRef(Py_None);
        goto done;
    }
    /* -- process: counted, used */
    PyObject *counters = PyObject_GetAttr(est, s_counters);
    if (counters == NULL)
        goto done;
    PyObject *count = PyDict_Check(counters) ? PyDict_GetItemWithError(counters, s_updates) : NULL;
    PyObject *next = count ? PyNumber_Add(count, PyTuple_GET_ITEM(small_ints, 0)) : NULL;
    int bad = next == NULL || PyDict_SetItem(counters, s_updates, next);
    Py_XDECREF(next);
    Py_DECREF(counters);
    if (bad) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_TypeError, "process_common: counters must be a dict holding 'updates'");
        goto done;
    }
    if (PyObject_SetAttr(est, s_rejected, Py_None))
        goto done;
    double stamp;
    if (as_double(o_stamp, &stamp))
        goto done;
    o_t = PyFloat_FromDouble(stamp * 1e-9); /* m.stamp_ns * 1e-9 */
    o_dt = PyFloat_FromDouble(dt);
    if (o_t == NULL || o_dt == NULL)
        goto done;
    coast = PyObject_GetAttr(est, s_coast);
    if (coast == NULL)
        goto done;
    if (coast != Py_None) { /* the coast regression's push (power state: unknown without a power measurement) */
        PyObject *power = power_valid ? PyObject_CallMethodOneArg(est, s_power_state, m) : PyLong_FromLong(0);
        if (power == NULL)
            goto done;
        PyObject *push_args[11] = {coast, o_t, o_v, o_g, PyTuple_GET_ITEM(m, 11), o_run, power, o_s,
                                   PyTuple_GET_ITEM(m, 12), PyTuple_GET_ITEM(m, 6), PyTuple_GET_ITEM(m, 7)};
        PyObject *code = coast_push(module, push_args, 11);
        long c = code ? PyLong_AsLong(code) : -1;
        Py_XDECREF(code);
        PyObject *changed = NULL;
        if (c == PUSH_IDLE)
            changed = Py_NewRef(Py_False);
        else if (c == PUSH_DETECT)
            changed = PyObject_CallMethodNoArgs(coast, s_detect);
        else if (c == PUSH_PYTHON && (tmp = PyObject_GetAttr(coast, s_push_python)) != NULL)
            changed = PyObject_Vectorcall(tmp, push_args + 1, 10, NULL);
        Py_CLEAR(tmp);
        Py_DECREF(power);
        flag = changed ? PyObject_IsTrue(changed) : -1;
        Py_XDECREF(changed);
        if (flag < 0)
            goto done;
        if (flag) {
            tmp = PyObject_CallMethodNoArgs(est, s_take_coast_resistance);
            if (tmp == NULL)
                goto done;
            Py_CLEAR(tmp);
        }
    }
    /* -- _step: the speed slope, the variances, the common step */
    slope = PyObject_GetAttr(est, s_slope_);
    if (slope == NULL)
        goto done;
    PyObject *slope_args[3] = {slope, o_t, o_v};
    o_a = slope_push(module, slope_args, 3);
    if (o_a == NULL)
        goto done;
    flag = attr_truth(config, s_use_measurement_variance);
    if (flag < 0)
        goto done;
    if (flag) {
        o_rs = Py_NewRef(PyTuple_GET_ITEM(m, 6));
        o_rv = Py_NewRef(PyTuple_GET_ITEM(m, 7));
    } else {
        o_rs = PyObject_GetAttr(est, s_rs);
        o_rv = o_rs ? PyObject_GetAttr(est, s_rv) : NULL;
        if (o_rv == NULL)
            goto done;
    }
    PyObject *step_args[6] = {est, m, o_dt, o_a, o_rs, o_rv};
    common = common_step(module, step_args, 6);
    if (common == NULL)
        goto done;
    if (common == Py_None) { /* the readable chain from here (ResistanceEstimator._step_chain) */
        PyObject *chain_args[7] = {est, m, o_dt, o_t, o_a, o_rs, o_rv};
        result = PyObject_VectorcallMethod(s_step_chain, chain_args, 7, NULL);
        goto done;
    }
    /* -- _common_result: the NIS window (_nis_rule), the measurement remembered (_remember), the StepResult */
    PyObject *o_effort = PyTuple_GET_ITEM(common, 0), *o_u = PyTuple_GET_ITEM(common, 1);
    PyObject *o_nis = PyTuple_GET_ITEM(common, 2);
    double nis = PyFloat_AS_DOUBLE(o_nis), nis_sum;
    ring = PyObject_GetAttr(est, s_nis_ring);
    PyObject *entry = ring ? PyTuple_Pack(2, o_nis, PyTuple_GET_ITEM(small_ints, 1)) : NULL;
    bad = entry == NULL || call_append(ring, entry);
    Py_XDECREF(entry);
    if (bad || attr_double(est, s_nis_sum, &nis_sum))
        goto done;
    tmp = PyObject_GetAttr(est, s_nis_dof);
    long dofs = tmp ? PyLong_AsLong(tmp) : -1, window;
    Py_CLEAR(tmp);
    if (dofs == -1 && PyErr_Occurred())
        goto done;
    double total = nis_sum + nis;
    dofs += 2;
    tmp = PyObject_GetAttr(est, s_nis_window);
    window = tmp ? PyLong_AsLong(tmp) : -1;
    Py_CLEAR(tmp);
    if (window == -1 && PyErr_Occurred())
        goto done;
    Py_ssize_t length = PyObject_Length(ring);
    if (length < 0)
        goto done;
    if (length > window) {
        PyObject *old = PyObject_CallMethodNoArgs(ring, s_popleft);
        if (old == NULL)
            goto done;
        double old_nis;
        long old_dof = -1;
        bad = !PyTuple_Check(old) || PyTuple_GET_SIZE(old) != 2 || as_double(PyTuple_GET_ITEM(old, 0), &old_nis) ||
              ((old_dof = PyLong_AsLong(PyTuple_GET_ITEM(old, 1))) == -1 && PyErr_Occurred());
        Py_DECREF(old);
        if (bad) {
            if (!PyErr_Occurred())
                PyErr_SetString(PyExc_TypeError, "process_common: the NIS window holds (nis, dof) pairs");
            goto done;
        }
        total -= old_nis;
        dofs -= old_dof;
        length -= 1;
    }
    if (set_double(est, s_nis_sum, total))
        goto done;
    tmp = PyLong_FromLong(dofs);
    if (tmp == NULL || PyObject_SetAttr(est, s_nis_dof, tmp))
        goto done;
    Py_CLEAR(tmp);
    int inconsistent = 0;
    if (!(length < window || dofs <= 0)) {
        tmp = PyObject_GetAttr(est, s_nis_limit);
        PyObject *limit = tmp ? PySequence_GetItem(tmp, (Py_ssize_t)dofs) : NULL;
        Py_CLEAR(tmp);
        double lim;
        bad = limit == NULL || as_double(limit, &lim);
        Py_XDECREF(limit);
        if (bad)
            goto done;
        inconsistent = total > lim;
    }
    if (inconsistent) { /* DEGRADED or the NIS reset: ResistanceEstimator._nis_inconsistent */
        PyObject *nis_args[4] = {est, o_s, o_v, health_ok};
        tmp = PyObject_VectorcallMethod(s_nis_inconsistent, nis_args, 4, NULL);
        if (tmp == NULL)
            goto done;
        if (!PyTuple_Check(tmp) || PyTuple_GET_SIZE(tmp) != 2) {
            PyErr_SetString(PyExc_TypeError, "process_common: _nis_inconsistent returns (health, nis_reset)");
            goto done;
        }
        health = Py_NewRef(PyTuple_GET_ITEM(tmp, 0));
        Py_CLEAR(tmp);
    } else {
        if (PyObject_SetAttr(est, s_degraded_steps, zero_int))
            goto done;
        health = Py_NewRef(health_ok);
    }
    /* _remember */
    tmp = PyTuple_Pack(3, PyTuple_GET_ITEM(m, 8), PyTuple_GET_ITEM(m, 9), PyTuple_GET_ITEM(m, 10));
    if (tmp == NULL || PyObject_SetAttr(est, s_last_stamp, o_stamp) || PyObject_SetAttr(est, s_zv_prev, o_v) ||
        PyObject_SetAttr(est, s_g_prev, o_g) || PyObject_SetAttr(est, s_pw_prev, tmp))
        goto done;
    Py_CLEAR(tmp);
    /* the published estimate (r at its mean: decoupled) */
    Py_CLEAR(x);
    x = PyObject_GetAttr(h, s_x);
    PyObject *P = x ? PyObject_GetAttr(h, s_P) : NULL;
    if (P == NULL)
        goto done;
    if (!PyList_CheckExact(x) || PyList_GET_SIZE(x) != 5) {
        Py_DECREF(P);
        PyErr_SetString(PyExc_TypeError, "process_common: the filter's x must be a list of 5");
        goto done;
    }
    double xr[5];
    for (int i = 0; i < 5; i++)
        if (as_double(PyList_GET_ITEM(x, i), &xr[i])) {
            Py_DECREF(P);
            goto done;
        }
    double vf = xr[1];
    PyObject *o_resistance = PyFloat_FromDouble(xr[2] + (xr[3] + xr[4] * vf) * vf); /* running_resistance */
    if (o_resistance == NULL) {
        Py_DECREF(P);
        goto done;
    }
    PyObject *items = PyTuple_Pack(16, PyList_GET_ITEM(x, 0), PyList_GET_ITEM(x, 1), PyList_GET_ITEM(x, 2),
                                   PyList_GET_ITEM(x, 3), PyList_GET_ITEM(x, 4), o_effort, o_a, o_resistance, o_g,
                                   o_nis, effort_computed, health, o_dt, o_u, Py_True, P);
    Py_DECREF(o_resistance);
    Py_DECREF(P);
    if (items == NULL)
        goto done;
    tmp = PyTuple_Pack(1, items);
    Py_DECREF(items);
    if (tmp == NULL)
        goto done;
    result = PyTuple_Type.tp_new((PyTypeObject *)step_result_type, tmp, NULL);
done:
    Py_XDECREF(h);
    Py_XDECREF(x);
    Py_XDECREF(run_id);
    Py_XDECREF(last_stamp);
    Py_XDECREF(diff);
    Py_XDECREF(o_dt);
    Py_XDECREF(o_t);
    Py_XDECREF(config);
    Py_XDECREF(o_rs);
    Py_XDECREF(o_rv);
    Py_XDECREF(coast);
    Py_XDECREF(slope);
    Py_XDECREF(o_a);
    Py_XDECREF(common);
    Py_XDECREF(ring);
    Py_XDECREF(tmp);
    Py_XDECREF(health);
    return result;
}

/* ---- module ---------------------------------------------------------------------------------------------- */

static PyMethodDef methods[] = {
    {"common_step", (PyCFunction)(void (*)(void))common_step, METH_FASTCALL,
     "common_step(est, m, dt, a_obs, rs, rv) -> (effort, input effort, nis) or None: ukf_fast.common_step_python."},
    {"coast_candidates", (PyCFunction)(void (*)(void))coast_candidates, METH_FASTCALL,
     "coast_candidates(t, v, g, run, power, by_speed, by_power, params): coast_regression.candidate_steps_python."},
    {"coast_push", (PyCFunction)(void (*)(void))coast_push, METH_FASTCALL,
     "coast_push(reg, t, v, g, tunnel, run_id, power, s, gamma, s_var, v_var) -> 0 (idle), 1 (detect) or 2 (the "
     "Python push): CoastRegression.push_python up to the detection."},
    {"slope_push", (PyCFunction)(void (*)(void))slope_push, METH_FASTCALL,
     "slope_push(slope, t, v) -> the slope: effort.SpeedSlope.push_python."},
    {"step_input", (PyCFunction)(void (*)(void))step_input, METH_FASTCALL,
     "step_input(StepInput, m) -> StepInput: ukf.StepInput.from_measurement."},
    {"configure", (PyCFunction)(void (*)(void))configure, METH_FASTCALL,
     "configure(StepInput, StepResult, MAX_SPEED, MAX_TRACK_FORCE, MAX_POSITION, MAX_POWER, variance_lo, "
     "variance_hi, HEALTH_OK, EFFORT_COMPUTED): what process_common needs of ukf_types.py."},
    {"process_common", (PyCFunction)(void (*)(void))process_common, METH_FASTCALL,
     "process_common(est, m) -> StepResult or None: ResistanceEstimator.process of a common sample."},
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
    INTERN(s_t_, "_t");
    INTERN(s_v_, "_v");
    INTERN(s_g_, "_g");
    INTERN(s_tun_, "_tun");
    INTERN(s_run_, "_run");
    INTERN(s_power_, "_power");
    INTERN(s_s_, "_s");
    INTERN(s_gamma_, "_gamma");
    INTERN(s_s_var_, "_s_var");
    INTERN(s_v_var_, "_v_var");
    INTERN(s_d2_, "_d2");
    INTERN(s_d3_, "_d3");
    INTERN(s_grade_errors_, "_grade_errors");
    INTERN(s_quantum_, "_quantum");
    INTERN(s_d2_seen_, "_d2_seen");
    INTERN(s_prior_floats_, "_prior_floats");
    INTERN(s_grade_seen_, "_grade_seen");
    INTERN(s_period_, "_period");
    INTERN(s_refresh_wait_, "_refresh_wait");
    INTERN(s_REFRESH, "REFRESH");
    INTERN(s_REFRESH_PERIODS, "REFRESH_PERIODS");
    INTERN(s_v_max_, "_v_max");
    INTERN(s_v_min_, "_v_min");
    INTERN(s_moving_before_, "_moving_before");
    INTERN(s_moved_, "_moved");
    INTERN(s_last_detect_, "_last_detect");
    INTERN(s_open_, "_open");
    INTERN(s_append, "append");
    INTERN(s_points_, "_points");
    INTERN(s_t_ref_, "_t_ref");
    INTERN(s_st_, "_st");
    INTERN(s_sv_, "_sv");
    INTERN(s_stt_, "_stt");
    INTERN(s_stv_, "_stv");
    INTERN(s_svv_, "_svv");
    INTERN(s_count_, "_count");
    INTERN(s_window, "window");
    INTERN(s_slope, "slope");
    INTERN(s_REFRESH_, "_REFRESH");
    INTERN(s_refresh_, "_refresh");
    INTERN(s_popleft, "popleft");
    INTERN(s_stamp_ns, "stamp_ns");
    INTERN(s_run_id, "run_id");
    INTERN(s_track_force, "track_force");
    INTERN(s_s_variance, "s_variance");
    INTERN(s_v_variance, "v_variance");
    INTERN(s_power_valid, "power_valid");
    INTERN(s_power_consumed, "power_consumed");
    INTERN(s_power_regenerated, "power_regenerated");
    INTERN(s_tunnel_fraction, "tunnel_fraction");
    INTERN(s_track_force_integral, "track_force_integral");
    INTERN(s_common, "_common");
    INTERN(s_common_step, "_common_step");
    INTERN(s_counters, "counters");
    INTERN(s_updates, "updates");
    INTERN(s_rejected, "rejected");
    INTERN(s_run_id_, "_run_id");
    INTERN(s_last_stamp, "_last_stamp");
    INTERN(s_config, "config");
    INTERN(s_max_dt, "max_dt");
    INTERN(s_use_measurement_variance, "use_measurement_variance");
    INTERN(s_rs, "_rs");
    INTERN(s_rv, "_rv");
    INTERN(s_coast, "_coast");
    INTERN(s_power_state, "_power_state");
    INTERN(s_detect, "_detect");
    INTERN(s_push_python, "push_python");
    INTERN(s_take_coast_resistance, "_take_coast_resistance");
    INTERN(s_slope_, "_slope");
    INTERN(s_step_chain, "_step_chain");
    INTERN(s_nis_ring, "_nis_ring");
    INTERN(s_nis_sum, "_nis_sum");
    INTERN(s_nis_dof, "_nis_dof");
    INTERN(s_nis_window, "_nis_window");
    INTERN(s_nis_limit, "_nis_limit");
    INTERN(s_nis_inconsistent, "_nis_inconsistent");
    INTERN(s_degraded_steps, "_degraded_steps");
    INTERN(s_pw_prev, "_pw_prev");
#undef INTERN
    if ((float_zero = PyFloat_FromDouble(0.0)) == NULL)
        return NULL;
    if ((zero_int = PyLong_FromLong(0)) == NULL)
        return NULL;
    if ((small_ints = Py_BuildValue("(ii)", 1, 2)) == NULL) /* 1 (a count) and 2 (the update's dof) */
        return NULL;
    return PyModule_Create(&module);
}
