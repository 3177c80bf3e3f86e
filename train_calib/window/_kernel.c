/* train_calib.window._kernel: the streaming RMSE window fit of fast.py in C (same formulas, same order).
 *
 * fit(xy, upper, upper_tol, params, pattern, below_zero) with
 *   xy          (n, 4) float64, C-contiguous: [x y] of the window's rows, x = (1, v, v^2 ...) >= 0
 *   upper       (n,) float64: eq. 6/7 right-hand side, N/kg (inf: no constraint)
 *   upper_tol   (n,) float64: upper + 1e-12 max(1, |upper|), the feasibility test
 *   params      float64: lo0 lo1 lo2 hi0 hi1 hi2 max_condition k speed_1..speed_k davis_1..davis_k
 *               (bounds of r0, r1, r2 in N/kg units; reference speeds in m/s; the train's r(v) there)
 *   pattern     the last window's active set, code 9 (p0 + 1) + 3 (p1 + 1) + (p2 + 1), p in {-1, 0, 1}
 *   below_zero  rows with upper_tol < 0, or -1 to count them here
 * returns (status, pattern, constrained, condition, theta0, theta1, theta2, squares, relative_error, mean_speed,
 * dropped): status 0: the fit (theta in N/kg units, squares = ||x theta - y||^2; constrained: an eq. 6/7 row
 * binds, solved by the LSI); status 1: a case this kernel leaves to fast.py's Python path (too few rows, a
 * zero column, a condition number above max_condition, no active set found, inconsistent eq. 6/7 rows); the
 * other values are then meaningless.
 *
 * The QR factor is Householder's (LAPACK dgeqr2's reflectors), the scaled condition number the closed
 * form of fast._scaled_condition or, where that is loose, one-sided Jacobi singular values (LAPACK dgesdd
 * in Python), the LSI fast._lsi's reduction with Lawson & Hanson's NNLS (scipy's nnls in Python): equal to
 * round-off. Agreement with the Python path: test/window/test_window_kernel.py.
 *
 * Window(params): the streaming calibrator's window (steps with their regimes, rows, running speed extremes)
 * and fit() on its own arrays, calibrator._PyWindow's twin.
 *
 * Memory check after a change (the window tests on an ASan/UBSan build, then the normal build back):
 *   gcc -O1 -g -std=c99 -fsanitize=address,undefined -fPIC -shared -I"$(.venv/bin/python -c 'import sysconfig;
 *     print(sysconfig.get_paths()["include"])')" train_calib/window/_kernel.c -o train_calib/window/_kernel.cpython-311-x86_64-linux-gnu.so
 *   ASAN_OPTIONS=detect_leaks=0 LD_PRELOAD="$(gcc -print-file-name=libasan.so):$(gcc -print-file-name=libubsan.so)"
 *     .venv/bin/python -m pytest -n0 -p no:cacheprovider test/window
 *   .venv/bin/python setup.py -q build_ext --inplace --force   (the normal build again)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

#define STATUS_OK 0
#define STATUS_PYTHON 1
#define STACK_ROWS 512

typedef struct {
    double a[3][4]; /* scaled R3 and c: rows (r00 r01 r02 c0), (0 r11 r12 c1), (0 0 r22 c2) */
    double lo[3], hi[3];
} Problem;

/* ---- QR: R of [x y] (4 x 4 upper triangle) by Householder reflections, as dgeqr2 ------------------ */

static void householder_r(const double *xy, Py_ssize_t n, double *work, double r[4][4]) {
    memcpy(work, xy, (size_t)n * 4 * sizeof(double));
    for (int j = 0; j < 4; j++) {
        double alpha = work[j * 4 + j], xnorm2 = 0.0;
        for (Py_ssize_t i = j + 1; i < n; i++) {
            double value = work[i * 4 + j];
            xnorm2 += value * value;
        }
        double beta = alpha, tau = 0.0;
        if (xnorm2 > 0.0) {
            beta = -copysign(hypot(alpha, sqrt(xnorm2)), alpha);
            tau = (beta - alpha) / beta;
            double scal = 1.0 / (alpha - beta);
            for (Py_ssize_t i = j + 1; i < n; i++)
                work[i * 4 + j] *= scal;
        }
        r[j][j] = beta;
        if (tau == 0.0) {
            for (int k = j + 1; k < 4; k++)
                r[j][k] = work[j * 4 + k];
            continue;
        }
        double w[4] = {0.0, 0.0, 0.0, 0.0}; /* w = A[j:, k]^T v, v = (1, work[j+1:, j]) */
        for (int k = j + 1; k < 4; k++)
            w[k] = work[j * 4 + k];
        for (Py_ssize_t i = j + 1; i < n; i++) {
            double vi = work[i * 4 + j];
            for (int k = j + 1; k < 4; k++)
                w[k] += vi * work[i * 4 + k];
        }
        for (int k = j + 1; k < 4; k++) {
            w[k] *= tau;
            work[j * 4 + k] -= w[k];
            r[j][k] = work[j * 4 + k];
        }
        for (Py_ssize_t i = j + 1; i < n; i++) {
            double vi = work[i * 4 + j];
            for (int k = j + 1; k < 4; k++)
                work[i * 4 + k] -= w[k] * vi;
        }
    }
}

/* ---- scaled condition number ------------------------------------------------------------------------ */

static double jacobi_condition(double b[3][3]) {
    /* one-sided Jacobi on the columns of b: the singular values are the final column norms */
    for (int sweep = 0; sweep < 60; sweep++) {
        int rotated = 0;
        for (int p = 0; p < 2; p++) {
            for (int q = p + 1; q < 3; q++) {
                double alpha = 0.0, beta = 0.0, gamma = 0.0;
                for (int i = 0; i < 3; i++) {
                    alpha += b[i][p] * b[i][p];
                    beta += b[i][q] * b[i][q];
                    gamma += b[i][p] * b[i][q];
                }
                if (fabs(gamma) <= 1e-17 * sqrt(alpha * beta))
                    continue;
                rotated = 1;
                double zeta = (beta - alpha) / (2.0 * gamma);
                double t = copysign(1.0, zeta) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
                double c = 1.0 / sqrt(1.0 + t * t), s = c * t;
                for (int i = 0; i < 3; i++) {
                    double bp = b[i][p], bq = b[i][q];
                    b[i][p] = c * bp - s * bq;
                    b[i][q] = s * bp + c * bq;
                }
            }
        }
        if (!rotated)
            break;
    }
    double smax = 0.0, smin = INFINITY;
    for (int j = 0; j < 3; j++) {
        double norm = sqrt(b[0][j] * b[0][j] + b[1][j] * b[1][j] + b[2][j] * b[2][j]);
        smax = norm > smax ? norm : smax;
        smin = norm < smin ? norm : smin;
    }
    return smin > 0.0 ? smax / smin : INFINITY;
}

static double scaled_condition(const double a[3][4]) {
    /* fast._scaled_condition: closed-form eigenvalues of B^T B where accurate, else Jacobi on B */
    double r00 = a[0][0], r01 = a[0][1], r02 = a[0][2], r11 = a[1][1], r12 = a[1][2], r22 = a[2][2];
    double n0 = fabs(r00), n1 = sqrt(r01 * r01 + r11 * r11), n2 = sqrt(r02 * r02 + r12 * r12 + r22 * r22);
    if (n0 == 0.0 || n1 == 0.0 || n2 == 0.0)
        return INFINITY;
    double b01 = r01 / n1, b11 = r11 / n1, b02 = r02 / n2, b12 = r12 / n2, b22 = r22 / n2;
    double sign = r00 > 0.0 ? 1.0 : -1.0;
    double g01 = sign * b01, g02 = sign * b02, g12 = b01 * b02 + b11 * b12;
    double det2 = (b11 * b22) * (b11 * b22);
    double p2 = (g01 * g01 + g02 * g02 + g12 * g12) / 3.0;
    if (p2 > 0.0 && det2 > 0.0) {
        double p = sqrt(p2);
        double q = g01 * g02 * g12 / (p2 * p);
        double l1 = 1.0 + 2.0 * p * cos(acos(q < -1.0 ? -1.0 : q > 1.0 ? 1.0 : q) / 3.0);
        double rest = 3.0 - l1;
        double disc = rest * rest - 4.0 * det2 / l1;
        double l2 = 0.5 * (rest + sqrt(disc > 0.0 ? disc : 0.0));
        if (1e-4 * l1 <= l2 && l2 <= 0.5 * l1)
            return sqrt(l1 * l2 / det2 * l1);
    }
    double b[3][3] = {{sign, b01, b02}, {0.0, b11, b12}, {0.0, 0.0, b22}};
    return jacobi_condition(b);
}

/* ---- the bounded least squares in three variables: KKT of the active sets ----------------------------- */

static int lstsq(int count, double columns[2][3], const double d[3], double out[2]) {
    /* fast._lstsq: one or two columns by modified Gram-Schmidt on [columns d]; 0 if singular */
    if (count == 0)
        return 1;
    double a0 = columns[0][0], a1 = columns[0][1], a2 = columns[0][2];
    double r11 = sqrt(a0 * a0 + a1 * a1 + a2 * a2);
    if (r11 == 0.0)
        return 0;
    double q0 = a0 / r11, q1 = a1 / r11, q2 = a2 / r11;
    double e1 = q0 * d[0] + q1 * d[1] + q2 * d[2];
    if (count == 1) {
        out[0] = e1 / r11;
        return 1;
    }
    double b0 = columns[1][0], b1 = columns[1][1], b2 = columns[1][2];
    double r12 = q0 * b0 + q1 * b1 + q2 * b2;
    b0 = b0 - r12 * q0;
    b1 = b1 - r12 * q1;
    b2 = b2 - r12 * q2;
    double r22 = sqrt(b0 * b0 + b1 * b1 + b2 * b2);
    if (r22 <= 1e-14 * r11)
        return 0;
    double e2 = (b0 * (d[0] - e1 * q0) + b1 * (d[1] - e1 * q1) + b2 * (d[2] - e1 * q2)) / r22;
    double x2 = e2 / r22;
    out[0] = (e1 - r12 * x2) / r11;
    out[1] = x2;
    return 1;
}

static int solve(const Problem *pr, const int pattern[3], double phi[3]) {
    /* fast._solve: least squares of R3 phi = c with the pattern's variables at their bounds; 0 if singular */
    const double(*a)[4] = pr->a;
    double r00 = a[0][0], r01 = a[0][1], r02 = a[0][2], c0 = a[0][3];
    double r11 = a[1][1], r12 = a[1][2], c1 = a[1][3], r22 = a[2][2], c2 = a[2][3];
    if (!(pattern[0] || pattern[1] || pattern[2])) {
        if (r00 == 0.0 || r11 == 0.0 || r22 == 0.0)
            return 0;
        double x2 = c2 / r22;
        double x1 = (c1 - r12 * x2) / r11;
        phi[0] = (c0 - r01 * x1 - r02 * x2) / r00;
        phi[1] = x1;
        phi[2] = x2;
        return 1;
    }
    double fixed[3];
    for (int j = 0; j < 3; j++)
        fixed[j] = pattern[j] < 0 ? pr->lo[j] : pattern[j] > 0 ? pr->hi[j] : 0.0;
    double f0 = fixed[0], f1 = fixed[1], f2 = fixed[2];
    double d[3] = {c0 - r00 * f0 - r01 * f1 - r02 * f2, c1 - r11 * f1 - r12 * f2, c2 - r22 * f2};
    const double all[3][3] = {{r00, 0.0, 0.0}, {r01, r11, 0.0}, {r02, r12, r22}};
    double columns[2][3];
    int count = 0;
    for (int j = 0; j < 3; j++)
        if (!pattern[j])
            memcpy(columns[count++], all[j], sizeof(all[j]));
    double values[2];
    if (!lstsq(count, columns, d, values))
        return 0;
    int next = 0;
    for (int j = 0; j < 3; j++)
        phi[j] = pattern[j] ? fixed[j] : values[next++];
    return 1;
}

static int kkt(const Problem *pr, const double phi[3], const int pattern[3], int corrected[3]) {
    /* fast._kkt: 1 if phi meets the KKT conditions with this active set, else 0 and the corrected set */
    const double(*a)[4] = pr->a;
    double r00 = a[0][0], r01 = a[0][1], r02 = a[0][2], c0 = a[0][3];
    double r11 = a[1][1], r12 = a[1][2], c1 = a[1][3], r22 = a[2][2], c2 = a[2][3];
    double x0 = phi[0], x1 = phi[1], x2 = phi[2];
    double e0 = r00 * x0 + r01 * x1 + r02 * x2 - c0;
    double e1 = r11 * x1 + r12 * x2 - c1;
    double e2 = r22 * x2 - c2;
    double size = sqrt(c0 * c0 + c1 * c1 + c2 * c2) + fabs(r00 * x0) + fabs(r01 * x1) + fabs(r02 * x2);
    size += fabs(r11 * x1) + fabs(r12 * x2) + fabs(r22 * x2);
    int ok = 1;
    for (int j = 0; j < 3; j++) {
        int p = pattern[j];
        corrected[j] = p;
        if (p == 0) {
            double margin = 1e-12 * (pr->hi[j] - pr->lo[j]);
            if (phi[j] < pr->lo[j] - margin) {
                corrected[j] = -1;
                ok = 0;
            } else if (phi[j] > pr->hi[j] + margin) {
                corrected[j] = 1;
                ok = 0;
            }
            continue;
        }
        double gradient, norm;
        if (j == 0) {
            gradient = r00 * e0;
            norm = fabs(r00);
        } else if (j == 1) {
            gradient = r01 * e0 + r11 * e1;
            norm = sqrt(r01 * r01 + r11 * r11);
        } else {
            gradient = r02 * e0 + r12 * e1 + r22 * e2;
            norm = sqrt(r02 * r02 + r12 * r12 + r22 * r22);
        }
        double tolerance = 1e-12 * norm * size;
        if ((p < 0 && gradient < -tolerance) || (p > 0 && gradient > tolerance)) {
            corrected[j] = 0;
            ok = 0;
        }
    }
    return ok;
}

static int code_of(const int p[3]) { return 9 * (p[0] + 1) + 3 * (p[1] + 1) + (p[2] + 1); }

static void pattern_of(int code, int p[3]) {
    p[0] = code / 9 - 1;
    p[1] = (code / 3) % 3 - 1;
    p[2] = code % 3 - 1;
}

static void clip(const Problem *pr, double phi[3]) {
    for (int j = 0; j < 3; j++)
        phi[j] = phi[j] < pr->lo[j] ? pr->lo[j] : phi[j] > pr->hi[j] ? pr->hi[j] : phi[j];
}

static int box(const Problem *pr, int *code, double phi[3]) {
    /* fast.FastFit._box: from the last active set, each miss corrected; every set (fast.PATTERNS' order) if that cycles */
    long tried = 0;
    int current[3], corrected[3];
    pattern_of(*code, current);
    while (!(tried & (1L << code_of(current)))) {
        tried |= 1L << code_of(current);
        if (!solve(pr, current, phi))
            break;
        if (kkt(pr, phi, current, corrected)) {
            *code = code_of(current);
            clip(pr, phi);
            return 1;
        }
        memcpy(current, corrected, sizeof(current));
    }
    static const int order[3] = {0, -1, 1}; /* itertools.product((0, -1, 1), repeat=3) */
    for (int i = 0; i < 27; i++) {
        int pattern[3] = {order[i / 9], order[(i / 3) % 3], order[i % 3]};
        if (tried & (1L << code_of(pattern)))
            continue;
        if (solve(pr, pattern, phi) && kkt(pr, phi, pattern, corrected)) {
            *code = code_of(pattern);
            clip(pr, phi);
            return 1;
        }
    }
    return 0;
}

/* ---- standard error of r(v) relative to the train's ---------------------------------------------------- */

static double relative_error(const double a[3][4], const double scale[3], double sigma, Py_ssize_t k,
                             const double *speeds, const double *davis) {
    /* fast.FastFit._relative_error */
    if (k == 0)
        return 0.0;
    double r00 = a[0][0], r01 = a[0][1], r02 = a[0][2], r11 = a[1][1], r12 = a[1][2], r22 = a[2][2];
    double d0 = 1.0, d1 = fabs(r11) / sqrt(r01 * r01 + r11 * r11);
    double d2 = fabs(r22) / sqrt(r02 * r02 + r12 * r12 + r22 * r22);
    double dmin = fmin(d0, fmin(d1, d2)), dmax = fmax(d0, fmax(d1, d2));
    if (dmin <= 1e-12 * dmax)
        return INFINITY;
    double worst = -INFINITY;
    for (Py_ssize_t i = 0; i < k; i++) {
        double speed = speeds[i];
        double w0 = 1.0 / scale[0] / r00;
        double w1 = (speed / scale[1] - r01 * w0) / r11;
        double w2 = (speed * speed / scale[2] - r02 * w0 - r12 * w1) / r22;
        double se = sigma * sqrt(w0 * w0 + w1 * w1 + w2 * w2);
        double ratio = davis[i] != 0.0 ? se / davis[i] : (se > 0.0 ? INFINITY : NAN);
        if (isnan(ratio))
            return NAN;
        worst = ratio > worst ? ratio : worst;
    }
    return worst;
}

/* ---- the window ----------------------------------------------------------------------------------------- */

/* ---- an eq. 6/7 row binds: Lawson & Hanson's LSI -> LDP -> NNLS on R3, as fast._lsi ------------------------ */

static int small_qr(const double *m, const Py_ssize_t *cols, int count, double q[4][4], double r[4][4]) {
    /* modified Gram-Schmidt, twice, on the columns cols of m (4 x K, column j at m + 4 j); 0 if the last is
     * (nearly) dependent on the others */
    for (int c = 0; c < count; c++) {
        const double *a = m + 4 * cols[c];
        double v[4] = {a[0], a[1], a[2], a[3]};
        double size = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3]);
        for (int i = 0; i < c; i++)
            r[i][c] = 0.0;
        for (int pass = 0; pass < 2; pass++) {
            for (int i = 0; i < c; i++) {
                double dot = q[i][0] * v[0] + q[i][1] * v[1] + q[i][2] * v[2] + q[i][3] * v[3];
                r[i][c] += dot;
                for (int l = 0; l < 4; l++)
                    v[l] -= dot * q[i][l];
            }
        }
        double norm = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3]);
        if (!(norm > 1e-12 * size))
            return 0;
        r[c][c] = norm;
        for (int l = 0; l < 4; l++)
            q[c][l] = v[l] / norm;
    }
    return 1;
}

static int passive_solve(const double *m, const Py_ssize_t *cols, int count, const double t[4], double z[4]) {
    /* least squares of the passive columns against t; 0 if they are (nearly) dependent */
    double q[4][4], r[4][4];
    if (!small_qr(m, cols, count, q, r))
        return 0;
    for (int c = count - 1; c >= 0; c--) {
        double value = q[c][0] * t[0] + q[c][1] * t[1] + q[c][2] * t[2] + q[c][3] * t[3];
        for (int i = c + 1; i < count; i++)
            value -= r[c][i] * z[i];
        z[c] = value / r[c][c];
    }
    return 1;
}

static int nnls4(const double *m, Py_ssize_t size, const double t[4], double *u, char *flags, Py_ssize_t max_iter) {
    /* Lawson & Hanson's NNLS: u >= 0 minimising ||m u - t|| for m 4 x size (column j at m + 4 j); 0 if the
     * iterations run out. flags: 1 passive, 2 left out until the next column enters (dependent or z <= 0). */
    Py_ssize_t passive[4];
    int count = 0;
    memset(flags, 0, (size_t)size);
    for (Py_ssize_t j = 0; j < size; j++)
        u[j] = 0.0;
    Py_ssize_t iterations = 0;
    for (;;) {
        double resid[4] = {t[0], t[1], t[2], t[3]};
        for (int c = 0; c < count; c++)
            for (int l = 0; l < 4; l++)
                resid[l] -= m[4 * passive[c] + l] * u[passive[c]];
        Py_ssize_t best = -1;
        double top = 1e-13;
        for (Py_ssize_t j = 0; j < size; j++) {
            if (flags[j])
                continue;
            const double *a = m + 4 * j;
            double w = a[0] * resid[0] + a[1] * resid[1] + a[2] * resid[2] + a[3] * resid[3];
            if (w > top) {
                top = w;
                best = j;
            }
        }
        if (best < 0 || count == 4)
            return 1;
        passive[count] = best;
        double z[4];
        if (!passive_solve(m, passive, count + 1, t, z) || !(z[count] > 0.0)) {
            flags[best] = 2; /* the column cannot enter now */
            continue;
        }
        for (Py_ssize_t j = 0; j < size; j++)
            flags[j] &= 1;
        flags[best] = 1;
        count++;
        for (;;) {
            if (++iterations > max_iter)
                return 0;
            int positive = 1;
            for (int c = 0; c < count; c++)
                positive &= z[c] > 0.0;
            if (positive) {
                for (int c = 0; c < count; c++)
                    u[passive[c]] = z[c];
                break;
            }
            double alpha = INFINITY;
            int hit = -1;
            for (int c = 0; c < count; c++) {
                if (z[c] > 0.0)
                    continue;
                double ratio = u[passive[c]] / (u[passive[c]] - z[c]);
                if (ratio < alpha) {
                    alpha = ratio;
                    hit = c;
                }
            }
            int kept = 0;
            for (int c = 0; c < count; c++) {
                Py_ssize_t j = passive[c];
                u[j] += alpha * (z[c] - u[j]);
                if (c == hit || u[j] <= 0.0) {
                    u[j] = 0.0;
                    flags[j] = 0;
                } else {
                    passive[kept++] = j;
                }
            }
            count = kept;
            if (count == 0 || !passive_solve(m, passive, count, t, z))
                break;
        }
    }
}

static int lsi(const Problem *pr, double condition, const double *xy, const double *upper, const double *upper_tol,
               Py_ssize_t n, const double *params, const double scale[3], double phi[3]) {
    /* fast._lsi: min ||R3 phi - c|| s.t. the usable eq. 6/7 rows and the bounds; 0 where fast._lsi gives None */
    if (condition * 2e-7 > 1.0) /* fast._lsi's singular-value test (condition = that of R3, the columns scaled alike) */
        return 0;
    const double(*a)[4] = pr->a;
    double r00 = a[0][0], r01 = a[0][1], r02 = a[0][2], r11 = a[1][1], r12 = a[1][2], r22 = a[2][2];
    /* R3^-1 (upper triangular) and phi_ls = R3^-1 c */
    double v[3][3] = {{1.0 / r00, -r01 / (r00 * r11), (r01 * r12 - r02 * r11) / (r00 * r11 * r22)},
                      {0.0, 1.0 / r11, -r12 / (r11 * r22)},
                      {0.0, 0.0, 1.0 / r22}};
    double c[3] = {a[0][3], a[1][3], a[2][3]}, ls[3];
    for (int i = 0; i < 3; i++)
        ls[i] = v[i][0] * c[0] + v[i][1] * c[1] + v[i][2] * c[2];
    /* constraint rows g phi <= h: the bounds (phi <= hi, -phi <= -lo), then the rows feasible at the lower bounds;
     * room for all 6 + n: 4 doubles per column of m, one for u and one byte of flags */
    Py_ssize_t room = 6 + n;
    double *m = PyMem_Malloc((size_t)room * 6 * sizeof(double));
    if (m == NULL)
        return 0;
    double *u = m + 4 * room;
    char *flags = (char *)(u + room);
    int feasible = 1;
    Py_ssize_t column = 0;
    for (Py_ssize_t i = -6; i < n; i++) {
        double g[3], h;
        if (i < 0) {
            int j = (i + 6) % 3;
            double sign = i < -3 ? 1.0 : -1.0;
            g[0] = g[1] = g[2] = 0.0;
            g[j] = sign;
            h = i < -3 ? pr->hi[j] : -pr->lo[j];
        } else {
            const double *x = xy + 4 * i;
            if (!(isfinite(upper[i]) && x[0] * params[0] + x[1] * params[1] + x[2] * params[2] <= upper_tol[i]))
                continue;
            g[0] = x[0] / scale[0];
            g[1] = x[1] / scale[1];
            g[2] = x[2] / scale[2];
            h = upper[i];
        }
        double slack = h - (g[0] * ls[0] + g[1] * ls[1] + g[2] * ls[2]);
        feasible &= slack >= 0.0;
        double e[3]; /* g R3^-1 */
        for (int l = 0; l < 3; l++)
            e[l] = g[0] * v[0][l] + g[1] * v[1][l] + g[2] * v[2][l];
        double norm = sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
        norm = norm > 1e-300 ? norm : 1e-300;
        double *col = m + 4 * column++;
        col[0] = -e[0] / norm;
        col[1] = -e[1] / norm;
        col[2] = -e[2] / norm;
        col[3] = -slack / norm;
    }
    if (feasible) {
        memcpy(phi, ls, sizeof(ls));
        PyMem_Free(m);
        return 1;
    }
    Py_ssize_t size = column;
    /* LDP: min ||z|| s.t. (-g R3^-1) z >= g phi_ls - h, by NNLS on [E^T; f^T] against (0, 0, 0, 1) */
    const double target[4] = {0.0, 0.0, 0.0, 1.0};
    int ok = nnls4(m, size, target, u, flags, 50 * (size + 4));
    double resid[4] = {-target[0], -target[1], -target[2], -target[3]};
    for (Py_ssize_t j = 0; ok && j < size; j++)
        for (int l = 0; l < 4; l++)
            resid[l] += m[4 * j + l] * u[j];
    PyMem_Free(m);
    double length = sqrt(resid[0] * resid[0] + resid[1] * resid[1] + resid[2] * resid[2] + resid[3] * resid[3]);
    if (!ok || fabs(resid[3]) < 1e-12 || length < 1e-12)
        return 0; /* the constraints are inconsistent (or the NNLS did not finish): the Python path decides */
    double z[3] = {-resid[0] / resid[3] + c[0], -resid[1] / resid[3] + c[1], -resid[2] / resid[3] + c[2]};
    for (int i = 0; i < 3; i++)
        phi[i] = v[i][0] * z[0] + v[i][1] * z[1] + v[i][2] * z[2];
    clip(pr, phi);
    return 1;
}

typedef struct {
    int status, pattern, constrained; /* constrained: the LSI solved it (an eq. 6/7 row binds) */
    double condition, theta[3], squares, relative_error, mean_speed;
    Py_ssize_t dropped;
} Result;

static void fit_rows(const double *xy, const double *upper, const double *upper_tol, Py_ssize_t n,
                     const double *params, Py_ssize_t k, Py_ssize_t below_zero, double *work, Result *out) {
    out->status = STATUS_PYTHON;
    if (n < 4)
        return;
    double r[4][4];
    householder_r(xy, n, work, r);
    double r00 = r[0][0], r01 = r[0][1], r02 = r[0][2], r11 = r[1][1], r12 = r[1][2], r22 = r[2][2];
    double norm1 = sqrt(r01 * r01 + r11 * r11), norm2 = sqrt(r02 * r02 + r12 * r12 + r22 * r22);
    if (r00 == 0.0 || norm1 == 0.0 || norm2 == 0.0)
        return;
    double root_n = sqrt((double)n);
    double scale[3] = {fabs(r00) / root_n, norm1 / root_n, norm2 / root_n};
    Problem pr = {{{r00 / scale[0], r01 / scale[1], r02 / scale[2], r[0][3]},
                   {0.0, r11 / scale[1], r12 / scale[2], r[1][3]},
                   {0.0, 0.0, r22 / scale[2], r[2][3]}},
                  {0}, {0}};
    double condition = scaled_condition(pr.a);
    if (!(condition <= params[6]))
        return;
    int lo_zero = 1;
    for (int j = 0; j < 3; j++) {
        pr.lo[j] = params[j] * scale[j];
        pr.hi[j] = params[3 + j] * scale[j];
        lo_zero &= params[j] == 0.0;
    }
    Py_ssize_t dropped = 0;
    if (lo_zero && below_zero >= 0) {
        dropped = below_zero;
    } else {
        for (Py_ssize_t i = 0; i < n; i++) {
            const double *x = xy + 4 * i;
            dropped += !(x[0] * params[0] + x[1] * params[1] + x[2] * params[2] <= upper_tol[i]);
        }
    }
    double phi[3];
    if (!box(&pr, &out->pattern, phi))
        return;
    double theta[3] = {phi[0] / scale[0], phi[1] / scale[1], phi[2] / scale[2]};
    for (Py_ssize_t i = 0; i < n; i++) {
        const double *x = xy + 4 * i;
        if (x[0] * theta[0] + x[1] * theta[1] + x[2] * theta[2] <= upper_tol[i])
            continue;
        /* a row dropped (infeasible at the lower bounds) may be violated; any other binds: the LSI */
        if (!dropped || x[0] * params[0] + x[1] * params[1] + x[2] * params[2] <= upper_tol[i]) {
            if (!lsi(&pr, condition, xy, upper, upper_tol, n, params, scale, phi))
                return;
            out->constrained = 1;
            for (int j = 0; j < 3; j++)
                theta[j] = phi[j] / scale[j];
            break;
        }
    }
    double e0 = pr.a[0][0] * phi[0] + pr.a[0][1] * phi[1] + pr.a[0][2] * phi[2] - pr.a[0][3];
    double e1 = pr.a[1][1] * phi[1] + pr.a[1][2] * phi[2] - pr.a[1][3];
    double e2 = pr.a[2][2] * phi[2] - pr.a[2][3];
    double rho = r[3][3];
    double squares = e0 * e0 + e1 * e1 + e2 * e2 + rho * rho;
    out->relative_error = relative_error(pr.a, scale, sqrt(squares / (double)(n - 3)), k, params + 8, params + 8 + k);
    out->condition = condition;
    memcpy(out->theta, theta, sizeof(theta));
    out->squares = squares;
    out->dropped = dropped;
    out->mean_speed = r01 / r00; /* R's first row is q0^T [x y], q0 = -+ ones / sqrt(n) */
    out->status = STATUS_OK;
}

static PyObject *result_tuple(const Result *out, PyObject *extra) {
    /* (status, pattern, constrained, condition, theta0, theta1, theta2, squares, relative_error, mean_speed,
     * dropped) + extra (a tuple, or NULL); steals the reference to extra */
    PyObject *head = Py_BuildValue("(iiidddddddn)", out->status, out->pattern, out->constrained, out->condition,
                                   out->theta[0], out->theta[1], out->theta[2], out->squares, out->relative_error,
                                   out->mean_speed, out->dropped);
    if (head == NULL || extra == NULL) {
        Py_XDECREF(extra);
        return head;
    }
    PyObject *all = PySequence_Concat(head, extra);
    Py_DECREF(head);
    Py_DECREF(extra);
    return all;
}

static int check_params(const double *p, Py_ssize_t size) {
    /* the number k of reference speeds, or -1 (error set) if params is not lo[3] hi[3] max_condition k ... */
    double k = size >= 8 ? p[7] : -1.0;
    if (!(k >= 0.0 && k == floor(k) && (double)size == 8.0 + 2.0 * k)) {
        PyErr_SetString(PyExc_ValueError, "params: lo[3] hi[3] max_condition k speeds[k] davis[k]");
        return -1;
    }
    return (int)k;
}

static int float64_buffer(PyObject *obj, Py_buffer *view, int ndim, const char *name) {
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return 0;
    int ok = view->ndim == ndim && view->itemsize == 8 && view->format && strcmp(view->format, "d") == 0;
    if (ok && ndim == 2)
        ok = view->shape[1] == 4;
    if (!ok) {
        PyErr_Format(PyExc_ValueError, "%s: expected a C-contiguous float64 array of %d dimension(s)%s", name, ndim,
                     ndim == 2 ? " and 4 columns" : "");
        PyBuffer_Release(view);
        return 0;
    }
    return 1;
}

static PyObject *kernel_fit(PyObject *module, PyObject *const *args, Py_ssize_t nargs) {
    (void)module;
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "fit(xy, upper, upper_tol, params, pattern, below_zero) takes 6 arguments");
        return NULL;
    }
    int pattern = (int)PyLong_AsLong(args[4]);
    Py_ssize_t below_zero = PyLong_AsSsize_t(args[5]);
    if (PyErr_Occurred())
        return NULL;
    if (pattern < 0 || pattern > 26) {
        PyErr_SetString(PyExc_ValueError, "pattern: an active-set code 0..26");
        return NULL;
    }
    static const char *names[] = {"xy", "upper", "upper_tol", "params"};
    Py_buffer views[4];
    int held = 0;
    for (; held < 4; held++)
        if (!float64_buffer(args[held], &views[held], held == 0 ? 2 : 1, names[held]))
            break;
    PyObject *result = NULL;
    Py_ssize_t n = held == 4 ? views[0].shape[0] : 0;
    int k = -1;
    if (held < 4) {
        /* the error is set */
    } else if (views[1].shape[0] != n || views[2].shape[0] != n) {
        PyErr_SetString(PyExc_ValueError, "upper, upper_tol: one entry per row of xy");
    } else if ((k = check_params(views[3].buf, views[3].shape[0])) >= 0) {
        double stack[STACK_ROWS * 4];
        double *work = n <= STACK_ROWS ? stack : PyMem_Malloc((size_t)n * 4 * sizeof(double));
        if (work == NULL) {
            PyErr_NoMemory();
        } else {
            Result out = {.pattern = pattern};
            fit_rows(views[0].buf, views[1].buf, views[2].buf, n, views[3].buf, k, below_zero, work, &out);
            if (work != stack)
                PyMem_Free(work);
            result = result_tuple(&out, NULL);
        }
    }
    for (int i = 0; i < held; i++)
        PyBuffer_Release(&views[i]);
    return result;
}

/* ---- one step of the window's rows: model.StepModel in C (same operations, same order: equal bit for bit) ------ */

/* The step model's values by name (model.StepModel.values()): Python fills the array in the order of the names that
   the module exports (STEP_PARAM_NAMES, from this table), so the two sides agree by name, not by position; each
   name is bound to its index here, and step_model reads by the same indices. */
enum {
    SP_MASS, SP_ETA, SP_AUXILIARY_W, SP_TUNNEL_FACTOR, SP_TRACTION, SP_C0, SP_C2, SP_V_TRANSITION, SP_ADHESION,
    SP_ADHESIVE_FRACTION, SP_GAMMA, SP_GRAVITY, SP_DIFFERENCE_SCHEME, SP_MIN_SPEED, SP_MAX_GAP, SP_CONSTRAINT_SIGMA,
    SP_EFFORT_TOLERANCE, SP_CRUISE_TOLERANCE, SP_EXCLUDE_BRAKING, STEP_PARAMS
};
static const char *const STEP_PARAM_NAMES[STEP_PARAMS] = {
    [SP_MASS] = "mass", [SP_ETA] = "eta", [SP_AUXILIARY_W] = "auxiliary_w", [SP_TUNNEL_FACTOR] = "tunnel_factor",
    [SP_TRACTION] = "traction", [SP_C0] = "c0", [SP_C2] = "c2", [SP_V_TRANSITION] = "v_transition",
    [SP_ADHESION] = "adhesion", [SP_ADHESIVE_FRACTION] = "adhesive_fraction", [SP_GAMMA] = "gamma",
    [SP_GRAVITY] = "gravity", [SP_DIFFERENCE_SCHEME] = "difference_scheme", [SP_MIN_SPEED] = "min_speed",
    [SP_MAX_GAP] = "max_gap", [SP_CONSTRAINT_SIGMA] = "constraint_sigma", [SP_EFFORT_TOLERANCE] = "effort_tolerance",
    [SP_CRUISE_TOLERANCE] = "cruise_tolerance", [SP_EXCLUDE_BRAKING] = "exclude_braking",
};
#define SCHEME_FORWARD 0
#define SCHEME_TRAPEZOID 2

typedef struct {
    double mass, eta, auxiliary_w, tunnel_factor, c0, c2, v_transition, adhesive_fraction, gamma, gravity;
    double min_speed, max_gap, constraint_sigma, effort_tolerance, cruise_tolerance;
    int traction, adhesion, scheme, exclude_braking;
} StepModel;

typedef struct {
    double t, v, f, g, tau, var, lim; /* s, m/s, N/kg, N/kg, 0..1, (m/s)^2, N/kg */
    int regime;                       /* of the step that starts here: -1 from power */
} Sample;

static void step_model(const double *p, StepModel *m) {
    /* by the indices of STEP_PARAM_NAMES */
    *m = (StepModel){.mass = p[SP_MASS], .eta = p[SP_ETA], .auxiliary_w = p[SP_AUXILIARY_W],
                     .tunnel_factor = p[SP_TUNNEL_FACTOR], .traction = p[SP_TRACTION] != 0.0, .c0 = p[SP_C0],
                     .c2 = p[SP_C2], .v_transition = p[SP_V_TRANSITION], .adhesion = p[SP_ADHESION] != 0.0,
                     .adhesive_fraction = p[SP_ADHESIVE_FRACTION], .gamma = p[SP_GAMMA], .gravity = p[SP_GRAVITY],
                     .scheme = (int)p[SP_DIFFERENCE_SCHEME], .min_speed = p[SP_MIN_SPEED], .max_gap = p[SP_MAX_GAP],
                     .constraint_sigma = p[SP_CONSTRAINT_SIGMA], .effort_tolerance = p[SP_EFFORT_TOLERANCE],
                     .cruise_tolerance = p[SP_CRUISE_TOLERANCE], .exclude_braking = p[SP_EXCLUDE_BRAKING] != 0.0};
}

static PyObject *step_model_dict(const StepModel *m) {
    /* the fields as step_model read them, by name (the test that the names and the reads agree) */
    return Py_BuildValue("{sdsdsdsdsdsdsdsdsdsdsdsdsdsdsdsdsdsdsd}", "mass", m->mass, "eta", m->eta, "auxiliary_w",
                         m->auxiliary_w, "tunnel_factor", m->tunnel_factor, "traction", (double)m->traction, "c0",
                         m->c0, "c2", m->c2, "v_transition", m->v_transition, "adhesion", (double)m->adhesion,
                         "adhesive_fraction", m->adhesive_fraction, "gamma", m->gamma, "gravity", m->gravity,
                         "difference_scheme", (double)m->scheme, "min_speed", m->min_speed, "max_gap", m->max_gap,
                         "constraint_sigma", m->constraint_sigma, "effort_tolerance", m->effort_tolerance,
                         "cruise_tolerance", m->cruise_tolerance, "exclude_braking", (double)m->exclude_braking);
}

static double step_force(const StepModel *m, double v, double power_consumed, double power_regenerated) {
    double consumed = power_consumed - m->auxiliary_w;
    double wheel = (consumed > 0.0 ? m->eta * consumed : 0.0) - power_regenerated / m->eta;
    if (consumed < 0.0)
        wheel = wheel + consumed / m->eta;
    return v >= m->min_speed ? wheel / (m->min_speed > v ? m->min_speed : v) / m->mass : NAN;
}

static double step_limit(const StepModel *m, double v) {
    double limit = INFINITY;
    if (m->traction) {
        double envelope;
        if (v <= m->v_transition)
            envelope = m->c0 + 0.0 * v;
        else
            envelope = v > 0.0 ? m->c2 / (1e-12 > v ? 1e-12 : v) : INFINITY;
        envelope = 0.0 > envelope ? 0.0 : envelope; /* Python's max(envelope, 0.0), min(limit, ...) below */
        limit = envelope < limit ? envelope : limit;
    }
    if (m->adhesion) {
        double mu = 0.161 + 7.5 / (3.6 * v + 44.0);
        double adhesion = mu * m->gravity * m->adhesive_fraction / m->gamma;
        limit = adhesion < limit ? adhesion : limit;
    }
    return limit;
}

static int step_row(const StepModel *m, const Sample *s0, const Sample *s1, double row[8]) {
    /* model.StepModel.row: (x0, x1, x2, y, upper, v, acceleration, force); 0 if the step is not valid */
    double dt = s1->t - s0->t;
    if (!(dt > 0.0 && dt <= m->max_gap))
        return 0;
    double a = (s1->v - s0->v) / dt;
    double c20 = s0->v * s0->v * (1.0 + m->tunnel_factor * s0->tau);
    double x1, x2, f, g, v, lim;
    int speed_ok;
    if (m->scheme == SCHEME_FORWARD) {
        x1 = s0->v, x2 = c20, f = s0->f, g = s0->g, v = s0->v, lim = s0->lim;
        speed_ok = s0->v >= m->min_speed;
    } else {
        double c21 = s1->v * s1->v * (1.0 + m->tunnel_factor * s1->tau);
        x1 = 0.5 * (s0->v + s1->v), x2 = 0.5 * (c20 + c21);
        g = 0.5 * (s0->g + s1->g), v = 0.5 * (s0->v + s1->v);
        if (m->scheme == SCHEME_TRAPEZOID) {
            f = 0.5 * (s0->f + s1->f), lim = 0.5 * (s0->lim + s1->lim);
            speed_ok = s0->v >= m->min_speed && s1->v >= m->min_speed;
        } else {
            f = s0->f, lim = s0->lim;
            speed_ok = s0->v >= m->min_speed;
        }
    }
    double y = f - g - a;
    double variance = s0->var + s1->var;
    double margin = variance >= 0.0 ? m->constraint_sigma * sqrt(variance) / dt : NAN;
    double upper = lim - g - a + margin;
    if (!(speed_ok && isfinite(y) && isfinite(x1) && isfinite(x2)) || isnan(upper))
        return 0;
    double values[8] = {1.0, x1, x2, y, upper, v, a, f};
    memcpy(row, values, sizeof(values));
    return 1;
}

static int step_regime(const StepModel *m, double force, double acceleration) {
    /* model.StepModel.regime: COASTING 3, CRUISING 2, TRACTION 1, BRAKING 4 */
    if (fabs(force) <= m->effort_tolerance)
        return 3;
    if (fabs(acceleration) <= m->cruise_tolerance)
        return 2;
    return force > 0.0 ? 1 : 4;
}

/* ---- Window: the streaming calibrator's window (steps with their regimes, rows) and its fit -------------- */

/* calibrator._RegimeTally, _RowBuffer and the fit above in one object: Window(params), then per sample
 * add(end_ns, regime, row, keep), expire(min_ns), fit(pattern); view() copies the rows out for the Python
 * path. Storage: arrays used from start to stop, moved down or doubled when stop reaches the capacity. */

#define REGIMES 256 /* DrivingRegime.regime is a uint8 */

typedef struct {
    long long *ns;
    double *v;
    Py_ssize_t start, stop, cap;
} Extremes; /* (end_ns, v) of the rows that are the fastest (slowest) of the rows after them */

typedef struct {
    PyObject_HEAD
    double *params;
    Py_ssize_t k;
    /* steps: end_ns and regime (-1: not a valid step) */
    long long *step_ns;
    int *step_regime;
    Py_ssize_t s_start, s_stop, s_cap;
    Py_ssize_t counts[REGIMES];
    long long newest[REGIMES], sequence;
    /* rows: end_ns, [x y], upper, upper_tol, a negative entry in x */
    long long *row_ns;
    double *xy, *upper, *upper_tol, *work;
    char *negative;
    Py_ssize_t r_start, r_stop, r_cap, negatives, below_zero;
    Extremes fastest, slowest;
    /* the step model (model.StepModel) and the last sample pushed */
    StepModel step;
    double step_params[STEP_PARAMS]; /* as given, for pickling */
    int has_step, has_last;
    Sample last;
} Window;

static int grow(void **array, Py_ssize_t cap, size_t item) {
    void *bigger = PyMem_Realloc(*array, (size_t)cap * item);
    if (bigger == NULL) {
        PyErr_NoMemory();
        return 0;
    }
    *array = bigger;
    return 1;
}

static int room(void **columns[], const size_t sizes[], int count, Py_ssize_t *start, Py_ssize_t *stop,
                Py_ssize_t *cap) {
    /* room for one more entry at *stop in parallel arrays: their entries moved down to 0, or the arrays doubled */
    if (*stop < *cap)
        return 1;
    Py_ssize_t used = *stop - *start;
    if (*start > 0) {
        for (int c = 0; c < count; c++)
            memmove(*columns[c], (char *)*columns[c] + *start * sizes[c], (size_t)used * sizes[c]);
    } else {
        for (int c = 0; c < count; c++)
            if (!grow(columns[c], 2 * *cap, sizes[c]))
                return 0;
        *cap *= 2;
    }
    *start = 0;
    *stop = used;
    return 1;
}

static int steps_room(Window *w) {
    void **columns[] = {(void **)&w->step_ns, (void **)&w->step_regime};
    const size_t sizes[] = {sizeof(long long), sizeof(int)};
    return room(columns, sizes, 2, &w->s_start, &w->s_stop, &w->s_cap);
}

static int rows_room(Window *w) {
    /* the QR's work array grows with the rows (moving it down is harmless) */
    void **columns[] = {(void **)&w->row_ns, (void **)&w->xy, (void **)&w->upper, (void **)&w->upper_tol,
                        (void **)&w->negative, (void **)&w->work};
    const size_t sizes[] = {sizeof(long long), 4 * sizeof(double), sizeof(double), sizeof(double), 1,
                            4 * sizeof(double)};
    return room(columns, sizes, 6, &w->r_start, &w->r_stop, &w->r_cap);
}

static int extremes_push(Extremes *e, long long ns, double v, int fastest) {
    while (e->stop > e->start && (fastest ? e->v[e->stop - 1] <= v : e->v[e->stop - 1] >= v))
        e->stop--;
    void **columns[] = {(void **)&e->ns, (void **)&e->v};
    const size_t sizes[] = {sizeof(long long), sizeof(double)};
    if (!room(columns, sizes, 2, &e->start, &e->stop, &e->cap))
        return 0;
    e->ns[e->stop] = ns;
    e->v[e->stop++] = v;
    return 1;
}

static void window_clear(Window *w) {
    w->s_start = w->s_stop = w->r_start = w->r_stop = 0;
    w->negatives = w->below_zero = 0;
    w->fastest.start = w->fastest.stop = w->slowest.start = w->slowest.stop = 0;
    memset(w->counts, 0, sizeof(w->counts));
    memset(w->newest, 0, sizeof(w->newest));
    w->has_last = 0;
}

static void window_dealloc(Window *w) {
    PyMem_Free(w->params);
    PyMem_Free(w->step_ns);
    PyMem_Free(w->step_regime);
    PyMem_Free(w->row_ns);
    PyMem_Free(w->xy);
    PyMem_Free(w->upper);
    PyMem_Free(w->upper_tol);
    PyMem_Free(w->work);
    PyMem_Free(w->negative);
    PyMem_Free(w->fastest.ns);
    PyMem_Free(w->fastest.v);
    PyMem_Free(w->slowest.ns);
    PyMem_Free(w->slowest.v);
    Py_TYPE(w)->tp_free((PyObject *)w);
}

static Window *window_alloc(PyTypeObject *type, const double *params, Py_ssize_t size, const double *step_params,
                            Py_ssize_t cap) {
    /* a new, empty Window (params checked by the caller; step_params NULL: no step model) with room for cap entries */
    Window *w = (Window *)type->tp_alloc(type, 0);
    if (w == NULL)
        return NULL;
    w->k = check_params(params, size);
    if (step_params != NULL) {
        step_model(step_params, &w->step);
        memcpy(w->step_params, step_params, sizeof(w->step_params));
        w->has_step = 1;
    }
    cap = cap > 64 ? cap : 64;
    w->s_cap = w->r_cap = w->fastest.cap = w->slowest.cap = cap;
    w->params = PyMem_Malloc((size_t)size * sizeof(double));
    w->step_ns = PyMem_Malloc(cap * sizeof(long long));
    w->step_regime = PyMem_Malloc(cap * sizeof(int));
    w->row_ns = PyMem_Malloc(cap * sizeof(long long));
    w->xy = PyMem_Malloc(cap * 4 * sizeof(double));
    w->upper = PyMem_Malloc(cap * sizeof(double));
    w->upper_tol = PyMem_Malloc(cap * sizeof(double));
    w->work = PyMem_Malloc(cap * 4 * sizeof(double));
    w->negative = PyMem_Malloc(cap);
    w->fastest.ns = PyMem_Malloc(cap * sizeof(long long));
    w->fastest.v = PyMem_Malloc(cap * sizeof(double));
    w->slowest.ns = PyMem_Malloc(cap * sizeof(long long));
    w->slowest.v = PyMem_Malloc(cap * sizeof(double));
    if (!w->params || !w->step_ns || !w->step_regime || !w->row_ns || !w->xy || !w->upper || !w->upper_tol ||
        !w->work || !w->negative || !w->fastest.ns || !w->fastest.v || !w->slowest.ns || !w->slowest.v) {
        Py_DECREF(w);
        PyErr_NoMemory();
        return NULL;
    }
    memcpy(w->params, params, (size_t)size * sizeof(double));
    window_clear(w);
    return w;
}

static PyObject *window_new(PyTypeObject *type, PyObject *args, PyObject *kwargs) {
    PyObject *params_obj, *step_obj = Py_None;
    static char *keywords[] = {"params", "step_params", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwargs, "O|O:Window", keywords, &params_obj, &step_obj))
        return NULL;
    double step_params[STEP_PARAMS];
    if (step_obj != Py_None) {
        Py_buffer step_view;
        if (!float64_buffer(step_obj, &step_view, 1, "step_params"))
            return NULL;
        int ok = step_view.shape[0] == STEP_PARAMS;
        if (ok)
            memcpy(step_params, step_view.buf, sizeof(step_params));
        PyBuffer_Release(&step_view);
        if (!ok) {
            PyErr_Format(PyExc_ValueError, "step_params: the %d values of StepModel.params(STEP_PARAM_NAMES)",
                         STEP_PARAMS);
            return NULL;
        }
    }
    Py_buffer view;
    if (!float64_buffer(params_obj, &view, 1, "params"))
        return NULL;
    Window *w = NULL;
    if (check_params(view.buf, view.shape[0]) >= 0)
        w = window_alloc(type, view.buf, view.shape[0], step_obj != Py_None ? step_params : NULL, 64);
    PyBuffer_Release(&view);
    return (PyObject *)w;
}

static int add_step(Window *w, long long end_ns, int regime, const double *row, int keep) {
    /* a step ending at end_ns with its regime, or not valid (row NULL); its row kept for the fit if keep */
    if (!steps_room(w))
        return 0;
    w->step_ns[w->s_stop] = end_ns;
    w->step_regime[w->s_stop++] = row != NULL ? regime : -1;
    if (row != NULL && regime >= 0) {
        w->counts[regime]++;
        w->newest[regime] = ++w->sequence;
    }
    if (row == NULL || !keep)
        return 1;
    if (!rows_room(w))
        return 0;
    Py_ssize_t i = w->r_stop;
    double upper = row[4], upper_tol = upper + 1e-12 * fmax(1.0, fabs(upper));
    w->row_ns[i] = end_ns;
    memcpy(w->xy + 4 * i, row, 4 * sizeof(double));
    w->upper[i] = upper;
    w->upper_tol[i] = upper_tol;
    w->below_zero += upper_tol < 0.0;
    w->negative[i] = row[0] < 0.0 || row[1] < 0.0 || row[2] < 0.0;
    w->negatives += w->negative[i];
    w->r_stop++;
    return extremes_push(&w->fastest, end_ns, row[1], 1) && extremes_push(&w->slowest, end_ns, row[1], 0);
}

static int regime_code(long regime) {
    if (regime < -1 || regime >= REGIMES) {
        PyErr_SetString(PyExc_ValueError, "regime: -1 (no valid step) or a DrivingRegime code 0..255");
        return 0;
    }
    return 1;
}

static PyObject *window_add(Window *w, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "add(end_ns, regime, row, keep) takes 4 arguments");
        return NULL;
    }
    long long end_ns = PyLong_AsLongLong(args[0]);
    long regime = PyLong_AsLong(args[1]);
    int keep = PyObject_IsTrue(args[3]);
    if (PyErr_Occurred() || !regime_code(regime))
        return NULL;
    double row[5];
    int has_row = args[2] != Py_None;
    if (has_row) {
        if (!PyTuple_Check(args[2]) || PyTuple_GET_SIZE(args[2]) < 5) {
            PyErr_SetString(PyExc_ValueError, "row: a tuple (x0, x1, x2, y, upper, ...) or None");
            return NULL;
        }
        for (int j = 0; j < 5; j++)
            row[j] = PyFloat_AsDouble(PyTuple_GET_ITEM(args[2], j));
        if (PyErr_Occurred())
            return NULL;
    }
    if (!add_step(w, end_ns, (int)regime, has_row ? row : NULL, keep))
        return NULL;
    Py_RETURN_NONE;
}

static void expire(Window *w, long long min_ns);

static PyObject *window_push(Window *w, PyObject *const *args, Py_ssize_t nargs) {
    /* calibrator._PyWindow.push */
    if (nargs != 11) {
        PyErr_SetString(PyExc_TypeError, "push(end_ns, t, v, power_valid, power_consumed, power_regenerated, "
                                         "track_force, tunnel_fraction, v_variance, regime, min_ns) takes 11 arguments");
        return NULL;
    }
    if (!w->has_step) {
        PyErr_SetString(PyExc_ValueError, "push: this Window was made without step_params");
        return NULL;
    }
    long long end_ns = PyLong_AsLongLong(args[0]), min_ns = PyLong_AsLongLong(args[10]);
    double t = PyFloat_AsDouble(args[1]), v = PyFloat_AsDouble(args[2]);
    int power_valid = PyObject_IsTrue(args[3]);
    double consumed = PyFloat_AsDouble(args[4]), regenerated = PyFloat_AsDouble(args[5]);
    double g = PyFloat_AsDouble(args[6]), tau = PyFloat_AsDouble(args[7]), var = PyFloat_AsDouble(args[8]);
    long regime = PyLong_AsLong(args[9]);
    if (PyErr_Occurred() || !regime_code(regime))
        return NULL;
    const StepModel *m = &w->step;
    Sample sample = {t, v, power_valid ? step_force(m, v, consumed, regenerated) : NAN, g, tau, var,
                     step_limit(m, v), (int)regime};
    int invalid = 0;
    if (w->has_last) {
        double row[8];
        if (!step_row(m, &w->last, &sample, row)) {
            invalid = 1;
            if (!add_step(w, end_ns, -1, NULL, 0))
                return NULL;
        } else {
            int step_regime_code = w->last.regime >= 0 ? w->last.regime : step_regime(m, row[7], row[6]);
            int keep = !(m->exclude_braking && step_regime_code == 4);
            if (!add_step(w, end_ns, step_regime_code, row, keep))
                return NULL;
        }
    }
    w->last = sample;
    w->has_last = 1;
    expire(w, min_ns);
    return PyBool_FromLong(invalid);
}

static void expire(Window *w, long long min_ns) {
    while (w->s_start < w->s_stop && w->step_ns[w->s_start] <= min_ns) {
        int regime = w->step_regime[w->s_start++];
        if (regime >= 0)
            w->counts[regime]--;
    }
    while (w->r_start < w->r_stop && w->row_ns[w->r_start] <= min_ns) {
        w->negatives -= w->negative[w->r_start];
        w->below_zero -= w->upper_tol[w->r_start] < 0.0;
        w->r_start++;
    }
    while (w->fastest.start < w->fastest.stop && w->fastest.ns[w->fastest.start] <= min_ns)
        w->fastest.start++;
    while (w->slowest.start < w->slowest.stop && w->slowest.ns[w->slowest.start] <= min_ns)
        w->slowest.start++;
}

static PyObject *window_expire(Window *w, PyObject *arg) {
    long long min_ns = PyLong_AsLongLong(arg);
    if (min_ns == -1 && PyErr_Occurred())
        return NULL;
    expire(w, min_ns);
    Py_RETURN_NONE;
}

static PyObject *window_clear_method(Window *w, PyObject *Py_UNUSED(ignored)) {
    window_clear(w);
    Py_RETURN_NONE;
}

static int window_regime(const Window *w) {
    /* _RegimeTally.dominant: the most frequent regime; a tie goes to the newest step's; none: UNKNOWN (0) */
    int best = -1;
    for (int r = 0; r < REGIMES; r++) {
        if (w->counts[r] == 0)
            continue;
        if (best < 0 || w->counts[r] > w->counts[best] ||
            (w->counts[r] == w->counts[best] && w->newest[r] > w->newest[best]))
            best = r;
    }
    return best < 0 ? 0 : best;
}

static double window_span(const Window *w) {
    if (w->fastest.stop == w->fastest.start)
        return 0.0;
    return w->fastest.v[w->fastest.start] - w->slowest.v[w->slowest.start];
}

static PyObject *window_fit(Window *w, PyObject *arg) {
    long pattern = PyLong_AsLong(arg);
    if (pattern == -1 && PyErr_Occurred())
        return NULL;
    if (pattern < 0 || pattern > 26) {
        PyErr_SetString(PyExc_ValueError, "pattern: an active-set code 0..26");
        return NULL;
    }
    Result out = {.pattern = (int)pattern};
    Py_ssize_t n = w->r_stop - w->r_start, start = w->r_start;
    if (w->negatives == 0)
        fit_rows(w->xy + 4 * start, w->upper + start, w->upper_tol + start, n, w->params, w->k, w->below_zero, w->work,
                 &out);
    else
        out.status = STATUS_PYTHON;
    return result_tuple(&out, Py_BuildValue("(ndi)", n, window_span(w), window_regime(w)));
}

static PyObject *window_view(Window *w, PyObject *Py_UNUSED(ignored)) {
    Py_ssize_t n = w->r_stop - w->r_start;
    return Py_BuildValue("(y#y#y#)", (const char *)(w->xy + 4 * w->r_start), n * 4 * (Py_ssize_t)sizeof(double),
                         (const char *)(w->upper + w->r_start), n * (Py_ssize_t)sizeof(double),
                         (const char *)(w->upper_tol + w->r_start), n * (Py_ssize_t)sizeof(double));
}

static PyObject *window_get_steps(Window *w, void *Py_UNUSED(closure)) {
    return PyLong_FromSsize_t(w->s_stop - w->s_start);
}

static PyObject *window_get_rows(Window *w, void *Py_UNUSED(closure)) {
    return PyLong_FromSsize_t(w->r_stop - w->r_start);
}

static PyObject *window_get_negatives(Window *w, void *Py_UNUSED(closure)) { return PyLong_FromSsize_t(w->negatives); }

static PyObject *window_get_below_zero(Window *w, void *Py_UNUSED(closure)) {
    return PyLong_FromSsize_t(w->below_zero);
}

static PyObject *window_get_speed_span(Window *w, void *Py_UNUSED(closure)) {
    return PyFloat_FromDouble(window_span(w));
}

static PyObject *window_get_regime(Window *w, void *Py_UNUSED(closure)) { return PyLong_FromLong(window_regime(w)); }

/* ---- pickling (copy.deepcopy, multiprocessing): the window's live entries as bytes ------------------------------- */

#define BYTES(ptr, count, item) (const char *)(ptr), (Py_ssize_t)(count) * (Py_ssize_t)(item)

static PyObject *restore_function; /* the module's _restore, set at import */
static PyTypeObject WindowType;

static PyObject *window_reduce(Window *w, PyObject *Py_UNUSED(ignored)) {
    Py_ssize_t size = 8 + 2 * w->k, steps = w->s_stop - w->s_start, rows = w->r_stop - w->r_start;
    Py_ssize_t fast = w->fastest.stop - w->fastest.start, slow = w->slowest.stop - w->slowest.start;
    Py_ssize_t r0 = w->r_start;
    PyObject *state = Py_BuildValue(
        "(y#y#y#y#y#y#Ly#y#y#y#y#nny#y#y#y#iy#)", BYTES(w->params, size, sizeof(double)),
        BYTES(w->step_params, w->has_step ? STEP_PARAMS : 0, sizeof(double)),
        BYTES(w->step_ns + w->s_start, steps, sizeof(long long)), BYTES(w->step_regime + w->s_start, steps, sizeof(int)),
        BYTES(w->counts, REGIMES, sizeof(Py_ssize_t)), BYTES(w->newest, REGIMES, sizeof(long long)), w->sequence,
        BYTES(w->row_ns + r0, rows, sizeof(long long)), BYTES(w->xy + 4 * r0, rows, 4 * sizeof(double)),
        BYTES(w->upper + r0, rows, sizeof(double)), BYTES(w->upper_tol + r0, rows, sizeof(double)),
        BYTES(w->negative + r0, rows, 1), w->negatives, w->below_zero,
        BYTES(w->fastest.ns + w->fastest.start, fast, sizeof(long long)),
        BYTES(w->fastest.v + w->fastest.start, fast, sizeof(double)),
        BYTES(w->slowest.ns + w->slowest.start, slow, sizeof(long long)),
        BYTES(w->slowest.v + w->slowest.start, slow, sizeof(double)), w->has_last, BYTES(&w->last, 1, sizeof(Sample)));
    if (state == NULL)
        return NULL;
    return Py_BuildValue("(O(N))", restore_function, state);
}

static int take(PyObject *state, int index, void *into, Py_ssize_t item, Py_ssize_t count) {
    /* copy bytes item state[index] of count entries of item bytes into `into`; -1: wrong length */
    PyObject *b = PyTuple_GET_ITEM(state, index);
    if (!PyBytes_Check(b) || PyBytes_GET_SIZE(b) != count * item)
        return -1;
    memcpy(into, PyBytes_AS_STRING(b), (size_t)(count * item));
    return 0;
}

static Py_ssize_t entries(PyObject *state, int index, Py_ssize_t item) {
    PyObject *b = PyTuple_GET_ITEM(state, index);
    return PyBytes_Check(b) && PyBytes_GET_SIZE(b) % item == 0 ? PyBytes_GET_SIZE(b) / item : -1;
}

static PyObject *kernel_restore(PyObject *module, PyObject *state) {
    /* the Window of a window_reduce state */
    (void)module;
    if (!PyTuple_Check(state) || PyTuple_GET_SIZE(state) != 20) {
        PyErr_SetString(PyExc_ValueError, "Window state: a tuple of 20 items from Window.__reduce__");
        return NULL;
    }
    Py_ssize_t size = entries(state, 0, sizeof(double)), n_step = entries(state, 1, sizeof(double));
    Py_ssize_t steps = entries(state, 2, sizeof(long long)), rows = entries(state, 7, sizeof(long long));
    Py_ssize_t fast = entries(state, 14, sizeof(long long)), slow = entries(state, 16, sizeof(long long));
    PyObject *params = PyTuple_GET_ITEM(state, 0), *step = PyTuple_GET_ITEM(state, 1);
    if (size < 0 || (n_step != 0 && n_step != STEP_PARAMS) || steps < 0 || rows < 0 || fast < 0 || slow < 0 ||
        check_params((const double *)PyBytes_AS_STRING(params), size) < 0) {
        PyErr_Clear();
        PyErr_SetString(PyExc_ValueError, "Window state: inconsistent item sizes");
        return NULL;
    }
    Py_ssize_t cap = steps > rows ? steps : rows;
    Window *w = window_alloc(&WindowType, (const double *)PyBytes_AS_STRING(params), size,
                             n_step ? (const double *)PyBytes_AS_STRING(step) : NULL, cap + 1);
    if (w == NULL)
        return NULL;
    long long sequence = PyLong_AsLongLong(PyTuple_GET_ITEM(state, 6));
    Py_ssize_t negatives = PyLong_AsSsize_t(PyTuple_GET_ITEM(state, 12));
    Py_ssize_t below_zero = PyLong_AsSsize_t(PyTuple_GET_ITEM(state, 13));
    long has_last = PyLong_AsLong(PyTuple_GET_ITEM(state, 18));
    if (PyErr_Occurred() || take(state, 2, w->step_ns, sizeof(long long), steps) ||
        take(state, 3, w->step_regime, sizeof(int), steps) || take(state, 4, w->counts, sizeof(Py_ssize_t), REGIMES) ||
        take(state, 5, w->newest, sizeof(long long), REGIMES) || take(state, 7, w->row_ns, sizeof(long long), rows) ||
        take(state, 8, w->xy, 4 * sizeof(double), rows) || take(state, 9, w->upper, sizeof(double), rows) ||
        take(state, 10, w->upper_tol, sizeof(double), rows) || take(state, 11, w->negative, 1, rows) ||
        take(state, 14, w->fastest.ns, sizeof(long long), fast) || take(state, 15, w->fastest.v, sizeof(double), fast) ||
        take(state, 16, w->slowest.ns, sizeof(long long), slow) || take(state, 17, w->slowest.v, sizeof(double), slow) ||
        take(state, 19, &w->last, sizeof(Sample), 1)) {
        Py_DECREF(w);
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_ValueError, "Window state: inconsistent item sizes");
        return NULL;
    }
    w->s_stop = steps;
    w->r_stop = rows;
    w->fastest.stop = fast;
    w->slowest.stop = slow;
    w->sequence = sequence;
    w->negatives = negatives;
    w->below_zero = below_zero;
    w->has_last = has_last != 0;
    return (PyObject *)w;
}

static PyMethodDef window_methods[] = {
    {"add", (PyCFunction)(void (*)(void))window_add, METH_FASTCALL,
     "add(end_ns, regime, row, keep): a step ending at end_ns (ns); regime -1 and row None: not a valid step; "
     "row (x0, x1, x2, y, upper, ...) as StepModel.row, kept among the rows if keep."},
    {"push", (PyCFunction)(void (*)(void))window_push, METH_FASTCALL,
     "push(end_ns, t, v, power_valid, power_consumed, power_regenerated, track_force, tunnel_fraction, v_variance, "
     "regime, min_ns) -> bool: a sample (ns, s, m/s, W, W, N/kg, 0..1, (m/s)^2, its regime or -1: from power): the "
     "step from the last sample added, then expire(min_ns); True if that step was not valid."},
    {"expire", (PyCFunction)window_expire, METH_O, "expire(min_ns): drop the steps ending at or before min_ns."},
    {"clear", (PyCFunction)window_clear_method, METH_NOARGS, "clear(): an empty window."},
    {"fit", (PyCFunction)window_fit, METH_O,
     "fit(pattern) -> (status, pattern, condition, theta0, theta1, theta2, squares, relative_error, mean_speed, "
     "dropped, n, speed_span, regime): the module's fit() of the rows (status 1 also with a negative x entry)."},
    {"view", (PyCFunction)window_view, METH_NOARGS, "view() -> (xy, upper, upper_tol) of the rows as float64 bytes."},
    {"__reduce__", (PyCFunction)window_reduce, METH_NOARGS, "pickling and copy.deepcopy: the live entries as bytes."},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef window_getset[] = {
    {"steps", (getter)window_get_steps, NULL, "steps in the window (valid or not)", NULL},
    {"rows", (getter)window_get_rows, NULL, "rows the fit uses", NULL},
    {"negatives", (getter)window_get_negatives, NULL, "rows with a negative entry in x", NULL},
    {"below_zero", (getter)window_get_below_zero, NULL, "rows with upper_tol < 0", NULL},
    {"speed_span", (getter)window_get_speed_span, NULL, "max - min speed of the rows, m/s", NULL},
    {"regime", (getter)window_get_regime, NULL, "dominant regime of the valid steps", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject WindowType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "train_calib.window._kernel.Window",
    .tp_basicsize = sizeof(Window),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "The streaming calibrator's window in C (see calibrator._PyWindow, the same in Python).",
    .tp_new = window_new,
    .tp_dealloc = (destructor)window_dealloc,
    .tp_methods = window_methods,
    .tp_getset = window_getset,
};

static PyObject *kernel_read_step_params(PyObject *module, PyObject *arg) {
    /* _read_step_params(step_params) -> dict: the step model as the Window reads it, by name */
    (void)module;
    Py_buffer view;
    if (!float64_buffer(arg, &view, 1, "step_params"))
        return NULL;
    if (view.shape[0] != STEP_PARAMS) {
        PyBuffer_Release(&view);
        PyErr_Format(PyExc_ValueError, "step_params: %d values", STEP_PARAMS);
        return NULL;
    }
    StepModel m;
    step_model(view.buf, &m);
    PyBuffer_Release(&view);
    return step_model_dict(&m);
}

static PyMethodDef kernel_methods[] = {
    {"_read_step_params", (PyCFunction)kernel_read_step_params, METH_O,
     "_read_step_params(step_params) -> dict: the step model as the Window reads it, by name (tests)."},
    {"_restore", (PyCFunction)kernel_restore, METH_O, "_restore(state) -> Window: unpickling (see Window.__reduce__)."},
    {"fit", (PyCFunction)(void (*)(void))kernel_fit, METH_FASTCALL,
     "fit(xy, upper_tol, params, pattern, below_zero) -> (status, pattern, condition, theta0, theta1, theta2, "
     "squares, relative_error, mean_speed, dropped): the RMSE window fit of train_calib.window.fast in C."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef kernel_module = {
    PyModuleDef_HEAD_INIT, "_kernel", "The streaming window fit's compiled kernel (see fast.py).", -1,
    kernel_methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__kernel(void) {
    if (PyType_Ready(&WindowType) < 0)
        return NULL;
    PyObject *module = PyModule_Create(&kernel_module);
    if (module == NULL)
        return NULL;
    restore_function = PyObject_GetAttrString(module, "_restore"); /* held for the module's lifetime */
    if (restore_function == NULL) {
        Py_DECREF(module);
        return NULL;
    }
    PyObject *names = PyTuple_New(STEP_PARAMS);
    for (Py_ssize_t i = 0; names != NULL && i < STEP_PARAMS; i++) {
        PyObject *name = PyUnicode_FromString(STEP_PARAM_NAMES[i]);
        if (name == NULL)
            Py_CLEAR(names);
        else
            PyTuple_SET_ITEM(names, i, name);
    }
    if (names == NULL || PyModule_AddObject(module, "STEP_PARAM_NAMES", names) < 0) {
        Py_XDECREF(names);
        Py_DECREF(module);
        return NULL;
    }
    Py_INCREF(&WindowType);
    if (PyModule_AddObject(module, "Window", (PyObject *)&WindowType) < 0) {
        Py_DECREF(&WindowType);
        Py_DECREF(module);
        return NULL;
    }
    return module;
}
