"""Rasterization constants shared by every backend; the same as gsplat 1.5.3 (classic, non-antialiased)."""

EPS2D = 0.3  # added to the 2D covariance diagonal (low-pass filter), pixels^2
NEAR_PLANE = 0.01  # metres; Gaussians with camera depth at or below are culled
FAR_PLANE = 1e10
ALPHA_MIN = 1.0 / 255.0  # a Gaussian contributes to a pixel only from this alpha up
ALPHA_MAX = 0.999  # alpha is clamped here so transmittance never reaches 0
T_MIN = 1e-4  # a pixel stops once its transmittance would drop to this or below
TILE_SIZE = 16  # pixels per tile side in the tile rasterizers
FOV_CLAMP = 0.3  # the projection Jacobian clamps x/z, y/z to 1.3x the half field of view
