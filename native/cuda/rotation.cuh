// Best rotation of a 3x3 cross-covariance in float, for the device and the host (LARAP_HD; the
// host tests are tests/cpp/test_rotation_fit.cpp).
//
// R maximises tr(R^T S) over proper rotations (S = sum q p^T, q deformed, p rest edge vectors).
// Horn's method: tr(R(q)^T S) = q^T N q for a unit quaternion q, N the symmetric 4x4 matrix
// built from S, so R is given by the eigenvector of N's largest eigenvalue. That eigenvector is
// found with cyclic Jacobi sweeps on the 4x4 matrix. No SVD branch cases: a reflection in S
// (det S < 0) gives the nearest proper rotation (U diag(1,1,-1) V^T) automatically, a rank
// deficient S any maximiser, S = 0 the identity.
#pragma once
#ifndef __CUDACC__
#include <cmath>  // fabsf, sqrtf, fmaxf on the host (tests/cpp/test_rotation_fit.cpp)
#endif

#include "host_device.h"

namespace larap {
namespace cuda_math {

template <int P, int Q>
LARAP_HD void jacobi_rotate(float (&a)[4][4], float (&v)[4][4]) {
  const float apq = a[P][Q];
  if (fabsf(apq) <= 1e-30f) return;
  const float theta = (a[Q][Q] - a[P][P]) / (2.0f * apq);
  const float t = (theta >= 0.0f ? 1.0f : -1.0f) / (fabsf(theta) + sqrtf(theta * theta + 1.0f));
  const float c = 1.0f / sqrtf(t * t + 1.0f);
  const float s = t * c;
  LARAP_UNROLL
  for (int k = 0; k < 4; ++k) {
    if (k == P || k == Q) continue;
    const float akp = a[k][P], akq = a[k][Q];
    const float nkp = c * akp - s * akq, nkq = s * akp + c * akq;
    a[k][P] = a[P][k] = nkp;
    a[k][Q] = a[Q][k] = nkq;
  }
  a[P][P] -= t * apq;
  a[Q][Q] += t * apq;
  a[P][Q] = a[Q][P] = 0.0f;
  LARAP_UNROLL
  for (int k = 0; k < 4; ++k) {
    const float vkp = v[k][P], vkq = v[k][Q];
    v[k][P] = c * vkp - s * vkq;
    v[k][Q] = s * vkp + c * vkq;
  }
}

// S row-major (S[3*a+b] = sum q_a p_b). Writes R row-major.
LARAP_HD void best_rotation_f(const float (&S)[9], float (&R)[9]) {
  float mx = 0.0f;
  LARAP_UNROLL
  for (int k = 0; k < 9; ++k) mx = fmaxf(mx, fabsf(S[k]));
  const float inv = mx > 0.0f ? 1.0f / mx : 0.0f;
  // M = S^T (Horn's M_ab = sum p_a q_b), scaled.
  const float Mxx = S[0] * inv, Mxy = S[3] * inv, Mxz = S[6] * inv;
  const float Myx = S[1] * inv, Myy = S[4] * inv, Myz = S[7] * inv;
  const float Mzx = S[2] * inv, Mzy = S[5] * inv, Mzz = S[8] * inv;
  float a[4][4] = {{Mxx + Myy + Mzz, Myz - Mzy, Mzx - Mxz, Mxy - Myx},
                   {Myz - Mzy, Mxx - Myy - Mzz, Mxy + Myx, Mzx + Mxz},
                   {Mzx - Mxz, Mxy + Myx, -Mxx + Myy - Mzz, Myz + Mzy},
                   {Mxy - Myx, Mzx + Mxz, Myz + Mzy, -Mxx - Myy + Mzz}};
  float v[4][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};
  LARAP_NO_UNROLL
  for (int sweep = 0; sweep < 6; ++sweep) {
    const float off =
        fabsf(a[0][1]) + fabsf(a[0][2]) + fabsf(a[0][3]) + fabsf(a[1][2]) + fabsf(a[1][3]) + fabsf(a[2][3]);
    if (off <= 1e-9f) break;
    jacobi_rotate<0, 1>(a, v);
    jacobi_rotate<0, 2>(a, v);
    jacobi_rotate<0, 3>(a, v);
    jacobi_rotate<1, 2>(a, v);
    jacobi_rotate<1, 3>(a, v);
    jacobi_rotate<2, 3>(a, v);
  }
  // Column of the largest eigenvalue (ties: the lowest index, the identity for S = 0).
  float best = a[0][0];
  float w = v[0][0], x = v[1][0], y = v[2][0], z = v[3][0];
  LARAP_UNROLL
  for (int k = 1; k < 4; ++k) {
    if (a[k][k] > best) {
      best = a[k][k];
      w = v[0][k];
      x = v[1][k];
      y = v[2][k];
      z = v[3][k];
    }
  }
  const float n2 = w * w + x * x + y * y + z * z;
  const float s = n2 > 0.0f ? 2.0f / n2 : 0.0f;
  R[0] = 1.0f - s * (y * y + z * z);
  R[1] = s * (x * y - w * z);
  R[2] = s * (x * z + w * y);
  R[3] = s * (x * y + w * z);
  R[4] = 1.0f - s * (x * x + z * z);
  R[5] = s * (y * z - w * x);
  R[6] = s * (x * z - w * y);
  R[7] = s * (y * z + w * x);
  R[8] = 1.0f - s * (x * x + y * y);
}

}  // namespace cuda_math
}  // namespace larap
