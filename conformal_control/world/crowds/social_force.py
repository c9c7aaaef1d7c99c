"""The social force model: Helbing & Molnár (1995) with the interaction of Moussaïd et al. (2009).

Each simulated pedestrian ``i`` accelerates as

    dv_i/dt = (v_pref_i - v_i) / tau + sum_{j != i} f_ij   (+ sigma xi_i),

the driving term of Helbing & Molnár (1995), "Social force model for pedestrian
dynamics", Phys. Rev. E 51 (relax within ``tau`` towards the preferred velocity), plus
the pairwise interaction fitted to controlled experiments by Moussaïd, Helbing, Garnier,
Johansson, Combe & Theraulaz (2009), "Experimental study of the behavioural mechanisms
underlying self-organization in human crowds", Proc. R. Soc. B 276. With ``e_ij`` the
unit vector from ``i`` to ``j`` and ``d_ij`` their centre distance:

    D_ij = lambda (v_i - v_j) + e_ij,   t_ij = D_ij / |D_ij|,   B = gamma |D_ij|,
    f_ij = -A exp(-d_ij / B) [exp(-(n' B theta_ij)^2) t_ij
                              + K_ij exp(-(n B theta_ij)^2) n_ij],

where ``theta_ij`` is the signed angle from ``t_ij`` to ``e_ij``, ``K_ij`` its sign and
``n_ij`` the left normal of ``t_ij``: the first term brakes, the second turns ``i`` away
from the side ``j`` is on. The robot and, in mixed mode, the replayed pedestrians act on
the simulated ones through the same interaction (with their own velocities) but are not
moved. The velocity is integrated by semi-implicit Euler and capped at ``v_max``
(Helbing & Molnár: 1.3 times the desired speed; the cap is set by
:class:`~conformal_control.world.crowds.crowd.Crowd`).

Two additions for agents of other sizes than a pedestrian (the robot): the interaction
is evaluated at the distance two pedestrians with the same gap between their bodies
would have, ``d_ij + r_i - r_j`` (exactly ``d_ij`` between equal bodies, as in the
paper), and overlapping bodies are pushed apart by the body force of Helbing, Farkas &
Vicsek (2000), "Simulating dynamical features of escape panic", Nature 407:
``k/m (r_i + r_j - d_ij) e_ji`` when ``d_ij < r_i + r_j`` (without it, Moussaïd's
interaction alone lets a pedestrian brush past a stopped robot with their centres 0.5 m
apart). The explicit integration of that stiff force needs ``dt < 2 / sqrt(k/m)``
(0.05 s at the default); the environment steps at the control rate, well below.

Parameters and their sources (the defaults are the papers' values):

==================== ========= ========================================================
``tau``              0.5 s     relaxation time, Helbing & Molnár (1995); Moussaïd 2009
``A``                4.5 m/s²  interaction strength, Moussaïd et al. (2009), fitted
``gamma``            0.35      range factor B = gamma ||D||, Moussaïd et al. (2009)
``lambda_importance`` 2.0      weight of the relative velocity in D, Moussaïd (2009)
``n``                2.0       angular decay of the turning term, Moussaïd (2009)
``n_prime``          3.0       angular decay of the braking term, Moussaïd (2009)
``contact_stiffness`` 1500/s²  body force k/m when bodies overlap, Helbing, Farkas &
                               Vicsek (2000): k = 1.2e5 kg/s², m = 80 kg
``neighbor_dist``    10 m      cut-off of the sum over agents (ours, for speed)
``noise``            0         fluctuation sigma (m s^-3/2), Helbing & Molnár's xi;
                               off by default (the model is then deterministic)
==================== ========= ========================================================

Why not ``pysocialforce`` (PyPI 1.1.2, the package this module was evaluated against):
measured on this 2-core machine it takes about 16 ms per step for 100 pedestrians
(``benchmarks/bench_crowds.py`` prints the figure and our ratio to it), 30 s of numba
compilation on the first step and 3 s to import; importing it sets the root logger to
DEBUG (flooding any application's log with numba's compiler traces) and creates a
``file.log`` in the working directory; it has no externally driven agent (the robot
would be pushed by the forces and must be overwritten after each step), one goal per
pedestrian (no waypoints), a desired speed tied to 1.3 x the *initial* speed (a
pedestrian standing at the start never walks), a config reader that silently replaces
a 0 by the default (``factor = 0`` is ignored), it appends a copy of the whole state to
a list at every step, and it has had no release since 2020. Its force code does not
wrap the angle difference into (-pi, pi]; ours does. This module computes the same
interaction (the benchmark prints the largest difference of the pairwise forces on
random states, with the package's ``factor`` set to our ``A``) in plain numpy.
"""

from __future__ import annotations

import numpy as np

from .base import CrowdModel
from .neighbors import neighbor_pairs

__all__ = ["SocialForceModel"]


class SocialForceModel(CrowdModel):
    """Helbing-Molnár driving term + Moussaïd et al. (2009) pairwise interaction, in numpy.

    Parameters
    ----------
    tau : float
        Relaxation time (s) towards the preferred velocity.
    A : float
        Interaction strength (m/s²).
    gamma : float
        Range factor of the interaction (dimensionless).
    lambda_importance : float
        Weight of the relative velocity in the interaction direction (s).
    n, n_prime : float
        Angular decay of the turning and the braking terms.
    contact_stiffness : float
        Body force per metre of overlap and per kilogram (1/s²) pushing apart bodies
        that overlap (centre distance below the sum of the radii); 0 disables it.
    neighbor_dist : float
        Agents farther than this (m, centre distance) are left out of the sum. At 10 m
        (default) the interaction is below 0.02 m/s² unless the two close in faster than
        2 m/s; ``inf`` sums over every agent as the papers do.
    noise : float
        Standard deviation of the fluctuation (m s^-3/2): each step adds
        ``noise * sqrt(dt) * N(0, 1)`` to every velocity component. 0 (default) makes the
        model deterministic; otherwise it draws from the generator given to ``reset``.
    """

    def __init__(
        self,
        tau: float = 0.5,
        A: float = 4.5,
        gamma: float = 0.35,
        lambda_importance: float = 2.0,
        n: float = 2.0,
        n_prime: float = 3.0,
        contact_stiffness: float = 1500.0,
        neighbor_dist: float = 10.0,
        noise: float = 0.0,
    ) -> None:
        self.tau = tau
        self.A = A
        self.gamma = gamma
        self.lambda_importance = lambda_importance
        self.n = n
        self.n_prime = n_prime
        self.contact_stiffness = contact_stiffness
        self.neighbor_dist = neighbor_dist
        self.noise = noise

    def _validate(self) -> None:
        self._check_positive(tau=self.tau, gamma=self.gamma, n=self.n, n_prime=self.n_prime)
        nd = self.neighbor_dist
        if not (isinstance(nd, (int, float, np.integer, np.floating)) and nd > 0):
            raise ValueError(f"neighbor_dist must be > 0 (inf: every agent), got {nd!r}")
        for name in ("A", "lambda_importance", "contact_stiffness", "noise"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.integer, np.floating)) and np.isfinite(v)):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
            if v < 0:
                raise ValueError(f"{name} must be >= 0, got {v!r}")

    def pair_forces(
        self,
        rel_x: np.ndarray,
        rel_y: np.ndarray,
        dv_x: np.ndarray,
        dv_y: np.ndarray,
        shift: np.ndarray | float = 0.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Moussaïd's interaction: acceleration (m/s²) of pedestrian ``i`` due to agent ``j``.

        Parameters
        ----------
        rel_x, rel_y : ndarray of shape (P,)
            Relative positions ``r_j - r_i`` (m).
        dv_x, dv_y : ndarray of shape (P,)
            Relative velocities ``v_i - v_j`` (m/s).
        shift : ndarray of shape (P,) or float
            Added to the centre distance in ``exp(-d / B)`` (``r_i - r_j`` in :meth:`step`,
            0 between equal bodies).

        Returns
        -------
        f_x, f_y : ndarray of shape (P,)
            Zero for coincident agents with equal velocities (no direction is defined).
        """
        dist = np.hypot(rel_x, rel_y)
        inv = np.divide(1.0, dist, out=np.zeros_like(dist), where=dist > 0.0)
        ex, ey = rel_x * inv, rel_y * inv
        lam = self.lambda_importance
        Dx = lam * dv_x + ex
        Dy = lam * dv_y + ey
        Dn = np.hypot(Dx, Dy)
        ok = Dn > 0.0
        invD = np.divide(1.0, Dn, out=np.zeros_like(Dn), where=ok)
        tx, ty = Dx * invD, Dy * invD
        theta = np.arctan2(tx * ey - ty * ex, tx * ex + ty * ey)  # from t to e, in (-pi, pi]
        B = self.gamma * Dn
        d_eq = np.maximum(dist + shift, 0.0)
        base = -self.A * np.exp(-d_eq * np.divide(1.0, B, out=np.zeros_like(B), where=ok))
        base[~ok] = 0.0
        brake = base * np.exp(-np.square(self.n_prime * B * theta))
        turn = base * np.sign(theta) * np.exp(-np.square(self.n * B * theta))
        return brake * tx - turn * ty, brake * ty + turn * tx

    def step(
        self,
        pos: np.ndarray,
        vel: np.ndarray,
        radius: np.ndarray,
        v_pref: np.ndarray,
        v_max: np.ndarray,
        other_pos: np.ndarray,
        other_vel: np.ndarray,
        other_radius: np.ndarray,
        dt: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        if pos.shape[0] == 0:
            return pos.copy(), vel.copy()
        n = pos.shape[0]
        acc = (v_pref - vel) / self.tau
        all_pos = np.concatenate([pos, other_pos])
        all_vel = np.concatenate([vel, other_vel])
        all_rad = np.concatenate([radius, other_radius])
        rows, cols, dx, dy = neighbor_pairs(pos, all_pos, self.neighbor_dist)
        if rows.size:
            ri, rj = radius[rows], all_rad[cols]
            fx, fy = self.pair_forces(
                dx, dy, vel[rows, 0] - all_vel[cols, 0], vel[rows, 1] - all_vel[cols, 1], ri - rj
            )
            if self.contact_stiffness > 0:
                dist = np.hypot(dx, dy)
                push = self.contact_stiffness * np.maximum(ri + rj - dist, 0.0)
                push = np.divide(push, dist, out=np.zeros_like(push), where=dist > 0)
                fx -= push * dx
                fy -= push * dy
            acc[:, 0] += np.bincount(rows, weights=fx, minlength=n)
            acc[:, 1] += np.bincount(rows, weights=fy, minlength=n)
        v = vel + dt * acc
        if self.noise > 0:
            v += self.noise * np.sqrt(dt) * self.rng_.standard_normal(v.shape)
        speed = np.hypot(v[:, 0], v[:, 1])
        over = speed > v_max
        if over.any():
            v[over] *= (v_max[over] / speed[over])[:, None]
        return pos + dt * v, v
