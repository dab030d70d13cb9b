"""A method whose pruning runs on its own schedule is one file
(``legs_per_pose.py``: LEGS pruning each pose after every n-th attempt made in
it) and runs through ``runtime.run`` with no change to the engine. Its
replacements are those of a plain NumPy replay of its own rollouts (the
reference's LEGS, pruned on the pose's own count), and not those of LEGS's
schedule replayed on the same rollouts."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from legs_per_pose import METHOD

from legs_jax import runtime, synthetic
from legs_jax.core import engine, keys, problem
from legs_jax.core.methods import legs
from legs_jax.core.methods.base import Config, check_declaration

HP = dict(s=1.0, prior_offset=1.0, delta=0.05, gamma=0.3, k=20, n=10)
H, R, OBJ = 400, 8, 7


class _Replay(legs.Reference):
    """The reference's LEGS, pruned at every n-th attempt of the pose itself
    (``own``) or at every n-th step (LEGS's own schedule)."""

    def __init__(self, problem, trial, hp, own: bool):
        super().__init__(problem, trial, hp)
        self.own = own
        self.tries = np.zeros(self.q.shape[0], int)

    def after_step(self, t: int, s: int) -> None:
        self.tries[s] += 1
        super().after_step(int(self.tries[s]) if self.own else t, s)


def test_method_with_its_own_pruning_schedule_runs_unchanged():
    check_declaration(METHOD)
    pb = synthetic.make_problem(seed=3, num_poses=3, num_grasps=120, num_trials=1)
    batch = problem.stack([pb])
    run = runtime.run(
        batch, METHOD, object_ids=[OBJ], num_rollouts=R, horizon=H,
        hparams=HP, check_every=None, progress=False,
    )  # fmt: skip
    # the same rollouts, step by step, from the engine's own program
    cfg = Config(pb.num_poses, pb.num_grasps, k=HP["k"], n=HP["n"])
    fn = runtime.compiled(METHOD, cfg, H, check_every=None, trajectory=True)
    tables = jax.tree.map(jnp.asarray, engine.make_tables(batch, [0]))
    ks = keys.rollout_keys(0, np.full(R, OBJ), np.zeros(R, int), np.arange(R))
    hp = METHOD.traced_hparams(
        **{n: jnp.full(R, HP[n], jnp.float32) for n in METHOD.traced}
    )
    out = jax.device_get(fn(tables, jnp.zeros(R, jnp.int32), ks, hp))
    np.testing.assert_array_equal(out["replacements"], run.replacements.reshape(-1))
    np.testing.assert_array_equal(out["final_gap"], run.final_gap.reshape(-1))
    assert out["replacements"].sum() > 0

    differs = False
    for r in range(R):
        want = {}
        for own in (True, False):
            twin = _Replay(pb, 0, HP, own)
            fields = (out[f][r] for f in ("pose", "grasp", "reward", "live"))
            steps = zip(*fields, strict=True)
            for t, (s, a, rew, live) in enumerate(steps, start=1):
                if live:  # as the reference's loop: a pose without grasps is skipped
                    twin.update(int(s), int(a), bool(rew))
                    twin.after_step(t, int(s))
            want[own] = twin.replacements
        assert out["replacements"][r] == want[True], f"rollout {r}"
        differs |= want[False] != want[True]
    assert differs  # the schedule is the method's: LEGS's would remove others
