// Shared by the loss kernels. Mirrors trainer/src/loss (photometric.rs, regularizers.rs).
#define SSIM_RADIUS 5
#define SSIM_SIGMA_PX 1.5
#define SSIM_C1 (0.01 * 0.01)
#define SSIM_C2 (0.03 * 0.03)
#define TV_EPSILON 1e-6

// The normalised 11-tap Gaussian window: weights[k + 5] for offsets k in [-5, 5].
void ssim_window(out float weights[2 * SSIM_RADIUS + 1]) {
    float total = 0.0;
    for (int j = -SSIM_RADIUS; j <= SSIM_RADIUS; ++j) {
        weights[j + SSIM_RADIUS] = exp(-float(j * j) / (2.0 * SSIM_SIGMA_PX * SSIM_SIGMA_PX));
        total += weights[j + SSIM_RADIUS];
    }
    for (int j = 0; j < 2 * SSIM_RADIUS + 1; ++j) {
        weights[j] /= total;
    }
}
