// Real spherical harmonics of degree 0-3 for the RGB colour of a primitive: the 3DGS basis and
// constants, term by term as the CPU reference (trainer/src/sh.rs; change both together). The
// colour of a primitive seen from camera centre c is max(0, sum_k Y_k(d) sh_k + 1/2) with
// d = (mu - c) / |mu - c|; degrees above 3 are read as 3 (k < min(K, 16)).

#define SH_C0 0.28209479177387814
#define SH_C1 0.4886025119029199
#define SH_C2_0 1.0925484305920792
#define SH_C2_1 -1.0925484305920792
#define SH_C2_2 0.31539156525252005
#define SH_C2_3 -1.0925484305920792
#define SH_C2_4 0.5462742152960396
#define SH_C3_0 -0.5900435899266435
#define SH_C3_1 2.890611442640554
#define SH_C3_2 -0.4570457994644658
#define SH_C3_3 0.3731763325901154
#define SH_C3_4 -0.4570457994644658
#define SH_C3_5 1.445305721320277
#define SH_C3_6 -0.5900435899266435

// Unit direction of v and its norm (direction +z and norm 0 for a zero vector), as sh.rs
// normalize.
vec3 sh_direction(vec3 v, out float norm) {
    norm = sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
    return norm > 0.0 ? vec3(v.x / norm, v.y / norm, v.z / norm) : vec3(0.0, 0.0, 1.0);
}

// Basis values Y_k(d), k < 16, for a unit direction d.
void sh_basis(vec3 d, out float y[16]) {
    float x = d.x, yy_ = d.y, z = d.z;
    float xx = x * x, yy = yy_ * yy_, zz = z * z;
    y[0] = SH_C0;
    y[1] = -SH_C1 * yy_;
    y[2] = SH_C1 * z;
    y[3] = -SH_C1 * x;
    y[4] = SH_C2_0 * x * yy_;
    y[5] = SH_C2_1 * yy_ * z;
    y[6] = SH_C2_2 * (2.0 * zz - xx - yy);
    y[7] = SH_C2_3 * x * z;
    y[8] = SH_C2_4 * (xx - yy);
    y[9] = SH_C3_0 * yy_ * (3.0 * xx - yy);
    y[10] = SH_C3_1 * x * yy_ * z;
    y[11] = SH_C3_2 * yy_ * (4.0 * zz - xx - yy);
    y[12] = SH_C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    y[13] = SH_C3_4 * x * (4.0 * zz - xx - yy);
    y[14] = SH_C3_5 * z * (xx - yy);
    y[15] = SH_C3_6 * x * (xx - 3.0 * yy);
}

// Gradients dY_k/dd, k < 16, for a unit direction d.
void sh_basis_grad(vec3 d, out vec3 dy[16]) {
    float x = d.x, y = d.y, z = d.z;
    float xx = x * x, yy = y * y, zz = z * z;
    dy[0] = vec3(0.0);
    dy[1] = SH_C1 * vec3(0.0, -1.0, 0.0);
    dy[2] = SH_C1 * vec3(0.0, 0.0, 1.0);
    dy[3] = SH_C1 * vec3(-1.0, 0.0, 0.0);
    dy[4] = SH_C2_0 * vec3(y, x, 0.0);
    dy[5] = SH_C2_1 * vec3(0.0, z, y);
    dy[6] = SH_C2_2 * vec3(-2.0 * x, -2.0 * y, 4.0 * z);
    dy[7] = SH_C2_3 * vec3(z, 0.0, x);
    dy[8] = SH_C2_4 * vec3(2.0 * x, -2.0 * y, 0.0);
    dy[9] = SH_C3_0 * vec3(6.0 * x * y, 3.0 * xx - 3.0 * yy, 0.0);
    dy[10] = SH_C3_1 * vec3(y * z, x * z, x * y);
    dy[11] = SH_C3_2 * vec3(-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z);
    dy[12] = SH_C3_3 * vec3(-6.0 * x * z, -6.0 * y * z, 6.0 * zz - 3.0 * xx - 3.0 * yy);
    dy[13] = SH_C3_4 * vec3(4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z);
    dy[14] = SH_C3_5 * vec3(2.0 * x * z, -2.0 * y * z, xx - yy);
    dy[15] = SH_C3_6 * vec3(3.0 * xx - 3.0 * yy, -6.0 * x * y, 0.0);
}
