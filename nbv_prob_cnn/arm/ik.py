"""Inverse kinematics of camera poses: damped least squares, batched, within joint limits.

One solver serves single requests (the seed from the current configuration plus random restarts
run side by side as one batch), many candidate views at once (:func:`solve_camera_poses`: each
target's seeds form a group that stops at its first convergence) and the capability map
(thousands of targets at once).

Per iteration, for every row: the pose error ``e = [p* - p, log(R* Rᵀ)]`` (metres, radians, world
axes), the step ``dq = Jᵀ (J Jᵀ + λ² I)⁻¹ e`` scaled down to at most ``max_step`` rad, and
``q ← clip(q + dq, lower, upper)``. A row converges when the position error is below
``position_tol`` and the rotation error below ``rotation_tol``; it gives up when its error norm
has not dropped by 1 % for ``patience`` iterations (stuck at a joint limit or a local minimum),
which keeps unreachable targets cheap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.arm.kinematics import CameraChain


@dataclass(frozen=True)
class IkSettings:
    """Solver parameters (metres, radians)."""

    damping: float = 0.05
    max_step: float = 0.4
    max_iterations: int = 80
    position_tol: float = 1e-3
    rotation_tol: float = 1e-2
    restarts: int = 8
    patience: int = 10  # a row stops after this many iterations without a 1 % error decrease


#: The default solver settings.
DEFAULT_IK = IkSettings()
#: A half turn about the optical (z) axis, applied on the right of a ``world_from_optical`` pose.
ROLL_HALF_TURN = np.diag([-1.0, -1.0, 1.0, 1.0])


def rotation_error(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Rotation vectors ``log(target · currentᵀ)`` ``(N, 3)`` of ``(N, 3, 3)`` rotations."""
    rel = target @ np.swapaxes(current, 1, 2)
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    vee = np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], axis=1)
    sin = np.sin(angle)
    small = sin < 1e-6
    scale = np.where(small, 0.5, angle / (2.0 * np.where(small, 1.0, sin)))
    out = vee * scale[:, None]
    near_pi = small & (cos < 0)
    if np.any(near_pi):  # angle ≈ π: axis from the symmetric part
        for i in np.nonzero(near_pi)[0]:
            sym = (rel[i] + np.eye(3)) / 2.0
            axis = sym[np.argmax(np.diag(sym))]
            out[i] = np.pi * axis / np.linalg.norm(axis)
    return out


def solve_batch(
    chain: CameraChain,
    targets: np.ndarray,
    seeds: np.ndarray,
    settings: IkSettings = DEFAULT_IK,
    stop_at_first: bool = False,
    groups: np.ndarray | None = None,
    persistent: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``targets (N, 4, 4)`` from ``seeds (N, n)``; with ``stop_at_first`` the iteration
    ends as soon as one row has converged (restarts of one target), or, with ``groups`` (a
    group id per row, e.g. the target's index), each group's rows stop as soon as one of
    them has converged (the rows converged at that iteration count as converged), except the
    rows where ``persistent (N,) bool`` is set: they run on until they converge or stall (e.g.
    the row seeded at the current configuration, whose solution is usually the nearest).

    Returns:
        ``(q (N, n), converged (N,) bool)``; unconverged rows hold their last iterate.
    """
    q = np.clip(np.array(seeds, dtype=np.float64).reshape(-1, chain.n), chain.lower, chain.upper)
    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 4, 4)
    grouped = stop_at_first and groups is not None
    group_ids = np.zeros(q.shape[0], dtype=np.int64)
    if grouped:
        group_ids = np.unique(np.asarray(groups), return_inverse=True)[1].ravel()
    group_done = np.zeros(int(group_ids.max()) + 1 if group_ids.size else 0, dtype=bool)
    converged = np.zeros(q.shape[0], dtype=bool)
    active = np.arange(q.shape[0])
    best = np.full(q.shape[0], np.inf)
    stalled = np.zeros(q.shape[0], dtype=np.int64)
    eye = np.eye(6) * settings.damping**2
    for _ in range(settings.max_iterations + 1):
        if active.size == 0:
            break
        poses, jac = chain.camera_poses(q[active], jacobian=True)
        assert jac is not None  # asked for
        goal = targets[active]
        error = np.concatenate([goal[:, :3, 3] - poses[:, :3, 3], rotation_error(goal[:, :3, :3], poses[:, :3, :3])], 1)
        done = (np.linalg.norm(error[:, :3], axis=1) < settings.position_tol) & (
            np.linalg.norm(error[:, 3:], axis=1) < settings.rotation_tol
        )
        converged[active[done]] = True
        if grouped:
            group_done[group_ids[active[done]]] = True
        elif stop_at_first and np.any(done):
            break
        norm = np.linalg.norm(error, axis=1)
        improved = norm < 0.99 * best[active]
        best[active] = np.where(improved, norm, best[active])
        stalled[active] = np.where(improved, 0, stalled[active] + 1)
        keep = ~done & (stalled[active] < settings.patience)
        if grouped:
            stop = group_done[group_ids[active]]
            if persistent is not None:
                stop &= ~persistent[active]
            keep &= ~stop
        active, jac, error = active[keep], jac[keep], error[keep]
        if active.size == 0:
            break
        jjt = jac @ np.swapaxes(jac, 1, 2) + eye
        step = np.einsum("nij,nj->ni", np.swapaxes(jac, 1, 2), np.linalg.solve(jjt, error[..., None])[..., 0])
        norm = np.abs(step).max(axis=1, keepdims=True)
        step *= np.minimum(1.0, settings.max_step / np.maximum(norm, 1e-12))
        q[active] = np.clip(q[active] + step, chain.lower, chain.upper)
    return q, converged


@dataclass
class IkResult:
    """A solved camera pose: full configuration ``q`` (``None`` if unreachable) and the chain's
    joint-space distance from the seed."""

    q: np.ndarray | None
    distance: float = float("inf")
    roll_flipped: bool = False  # q reaches the target turned 180° about its optical axis (roll_symmetric)


def solve_camera_pose(
    chain: CameraChain,
    target: np.ndarray,
    current_q: np.ndarray,
    rng: np.random.Generator,
    settings: IkSettings = DEFAULT_IK,
) -> IkResult:
    """IK of one ``world_from_optical`` pose from the current full configuration.

    The seed ``current_q`` and ``settings.restarts`` uniform random seeds within the limits run
    as one batch until one converges; of the rows converged at that iteration the closest
    (Euclidean, chain joints) to the seed wins.
    """
    current_q = np.asarray(current_q, dtype=np.float64)
    start = current_q[chain.q_index]
    seeds = np.vstack([start, rng.uniform(chain.lower, chain.upper, size=(settings.restarts, chain.n))])
    q, ok = solve_batch(chain, np.broadcast_to(target, (seeds.shape[0], 4, 4)), seeds, settings, stop_at_first=True)
    if not np.any(ok):
        return IkResult(None)
    distances = np.linalg.norm(q[ok] - start, axis=1)
    best = int(np.argmin(distances))
    return IkResult(chain.full_configuration(q[ok][best], current_q), float(distances[best]))


def solve_camera_poses(
    chain: CameraChain,
    targets: np.ndarray,
    current_q: np.ndarray,
    rng: np.random.Generator,
    settings: IkSettings = DEFAULT_IK,
    warm_seeds: np.ndarray | None = None,
    roll_symmetric: bool = False,
) -> list[IkResult]:
    """:func:`solve_camera_pose` of many ``world_from_optical`` targets ``(M, 4, 4)`` in one
    batch: per target the seed ``current_q``, its warm seed (``warm_seeds (M, n)`` chain
    configurations, e.g. the capability map's solution near the target; rows with NaN have
    none) and ``settings.restarts`` random seeds; each target's other rows stop at its first
    convergence, the row seeded at ``current_q`` runs until it converges or stalls, and of the
    rows converged the closest (chain joints) to ``current_q`` wins.

    With ``roll_symmetric`` the target turned 180° about its optical axis counts as the same
    view (a frustum symmetric about its axis covers the same cells: the gain is the same): a
    further row from ``current_q`` solves it, and a solution of it is marked ``roll_flipped``.
    """
    current_q = np.asarray(current_q, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 4, 4)
    count = targets.shape[0]
    if count == 0:
        return []
    start = current_q[chain.q_index]
    per_target = [np.broadcast_to(start, (count, chain.n))]
    if warm_seeds is not None:
        warm = np.asarray(warm_seeds, dtype=np.float64).reshape(count, chain.n)
        per_target.append(np.where(np.isfinite(warm), warm, start))  # no warm seed: the start again (harmless)
    per_target += [rng.uniform(chain.lower, chain.upper, size=(count, chain.n)) for _ in range(settings.restarts)]
    row_targets = [targets] * len(per_target)
    persistent_rows = [True] + [False] * (len(per_target) - 1)  # the current_q row runs on
    flipped_rows = [False] * len(per_target)
    if roll_symmetric:
        per_target.append(np.broadcast_to(start, (count, chain.n)))
        row_targets.append(targets @ ROLL_HALF_TURN)
        persistent_rows.append(True)
        flipped_rows.append(True)
    rows = len(per_target)
    seeds = np.stack(per_target, axis=1).reshape(-1, chain.n)  # target-major: rows of a target together
    goals = np.stack(row_targets, axis=1).reshape(-1, 4, 4)
    groups = np.repeat(np.arange(count), rows)
    persistent = np.tile(np.array(persistent_rows), count)
    q, ok = solve_batch(chain, goals, seeds, settings, True, groups, persistent)
    q, ok = q.reshape(count, rows, chain.n), ok.reshape(count, rows)
    results = []
    for m in range(count):
        if not np.any(ok[m]):
            results.append(IkResult(None))
            continue
        distances = np.where(ok[m], np.linalg.norm(q[m] - start, axis=1), np.inf)
        best = int(np.argmin(distances))
        results.append(IkResult(chain.full_configuration(q[m][best], current_q), float(distances[best]),
                                flipped_rows[best]))  # fmt: skip
    return results


def alternative_solutions(
    chain: CameraChain,
    target: np.ndarray,
    current_q: np.ndarray,
    rng: np.random.Generator,
    settings: IkSettings = DEFAULT_IK,
    min_separation: float = 0.2,
) -> list[IkResult]:
    """Other IK solutions of one pose (a redundant arm reaches it with different elbow/wrist
    placements): ``settings.restarts`` random seeds plus ``current_q``, each run to convergence,
    the converged ones sorted by chain-joint distance from the seed, keeping only solutions at
    least ``min_separation`` rad (Euclidean) from every one kept before."""
    return alternative_solutions_batch(chain, np.asarray(target)[None], current_q, rng, settings, min_separation)[0]


def alternative_solutions_batch(
    chain: CameraChain,
    targets: np.ndarray,
    current_q: np.ndarray,
    rng: np.random.Generator,
    settings: IkSettings = DEFAULT_IK,
    min_separation: float = 0.2,
) -> list[list[IkResult]]:
    """:func:`alternative_solutions` of many targets ``(M, 4, 4)`` in one batch (per target the
    same seeds, rules and order)."""
    current_q = np.asarray(current_q, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 4, 4)
    start = current_q[chain.q_index]
    rows = 1 + settings.restarts
    seeds = np.concatenate(
        [np.vstack([start, rng.uniform(chain.lower, chain.upper, size=(settings.restarts, chain.n))]) for _ in targets]
    ) if targets.shape[0] else np.zeros((0, chain.n))  # fmt: skip
    q, ok = solve_batch(chain, np.repeat(targets, rows, axis=0), seeds, settings)
    out = []
    for m in range(targets.shape[0]):
        found = q[m * rows : (m + 1) * rows][ok[m * rows : (m + 1) * rows]]
        distances = np.linalg.norm(found - start, axis=1)
        kept: list[np.ndarray] = []
        results = []
        for index in np.argsort(distances, kind="stable"):
            if all(np.linalg.norm(found[index] - other) >= min_separation for other in kept):
                kept.append(found[index])
                results.append(IkResult(chain.full_configuration(found[index], current_q), float(distances[index])))
        out.append(results)
    return out
