/* A serial chain's flange pose (chain.py, kernels.chain_pose).
 * Part of a library's one translation unit (controller.c), after common.h. */

/* ---------------------------------------------------------------- the flange pose
 *
 * Forward kinematics of a robot type's serial chain (chain.py), for the servo I/O process:
 * the flange in the base frame, to turn a wrist force/torque reading into the world frame
 * and take the tool's gravity out.  chain_pose is for the kernels here to call each tick;
 * kali_chain_pose exposes it to Python and the tests (chain.flange_pose is its reference).
 * Unlike the kernels above it equals its reference to ~1e-15, not bit for bit: numpy's 4x4
 * products go through BLAS, which sums (and fuses) in an order of its own. */

/* t = t * m, t the top 3x4 of a rigid transform (its bottom row is 0 0 0 1), m a row-major
 * 4x4 rigid transform: the 4x4 product's terms in its order, less those times m's zeros. */
static inline void affine_times(double *t, const double *m) {
    for (int k = 0; k < 3; k++) {
        double *row = t + 4 * k;
        double t0 = row[0], t1 = row[1], t2 = row[2], t3 = row[3];
        for (int j = 0; j < 4; j++) row[j] = t0 * m[j] + t1 * m[4 + j] + t2 * m[8 + j];
        row[3] += t3;
    }
}

/* The flange pose of an n-joint chain at joint angles q[0..n-1] (rad) into out (16 doubles,
 * row-major 4x4): origins[0] Rot(axes[0], q[0]) ... origins[n-1] Rot(axes[n-1], q[n-1])
 * origins[n].  origins: n + 1 row-major 4x4 rigid transforms, 16 doubles each, contiguous
 * (chain.Chain.origins: joint i's frame in its parent's at zero angle; the last one the
 * flange in joint n-1's frame); axes: n unit axes, 3 doubles each, in the joints' own frames.
 * Rot is Rodrigues' c I + s [a]x + (1 - c) a a^T, entry for entry as chain._rotation has it.
 * Rigid transforms only: the bottom rows are taken as 0 0 0 1 and out's is written so.
 * Everything on the stack, no libm call but sin and cos; out is written last. */
static void chain_pose(int64_t n, const double *origins, const double *axes, const double *q,
                       double *out) {
    double t[12]; /* the product so far, its top 3x4 */
    memcpy(t, origins, sizeof t);
    for (int64_t i = 0; i < n; i++) {
        if (i > 0) affine_times(t, origins + 16 * i);
        const double *a = axes + 3 * i;
        double x = a[0], y = a[1], z = a[2];
        double c = cos(q[i]), s = sin(q[i]), u = 1.0 - c;
        double r[9] = {
            u * x * x + c,     u * x * y - s * z, u * x * z + s * y,
            u * x * y + s * z, u * y * y + c,     u * y * z - s * x,
            u * x * z - s * y, u * y * z + s * x, u * z * z + c,
        };
        for (int k = 0; k < 3; k++) { /* t = t * [r 0; 0 1]: the translation stays */
            double *row = t + 4 * k;
            double t0 = row[0], t1 = row[1], t2 = row[2];
            for (int j = 0; j < 3; j++) row[j] = t0 * r[j] + t1 * r[3 + j] + t2 * r[6 + j];
        }
    }
    affine_times(t, origins + 16 * n);
    memcpy(out, t, sizeof t);
    out[12] = 0.0;
    out[13] = 0.0;
    out[14] = 0.0;
    out[15] = 1.0;
}

int64_t kali_chain_pose(ChainPoseArgs *a) {
    chain_pose(a->n, a->origins, a->axes, a->q, a->out);
    return 0;
}
