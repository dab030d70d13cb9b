"""From an experiment declaration (``experiments/<name>/sweep.py``) and the command
line to a plan: the arms to run, the objects and their problem files (catalogue, the
user's files, or synthetic ones for --smoke)."""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import os
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import experiments
import precompute
from legs_jax import results as res
from legs_jax import synthetic
from legs_jax.core import problem as problem_mod
from legs_jax.sweep.plan import (
    SMOKE,
    Arm,
    ExperimentPlan,
    ObjectEntry,
    SweepError,
    _check_plan,
    _method,
    _safe,
    make_arm,
    plan_chunks,
)
from precompute import problemset
from precompute.errors import PrecomputeError
from precompute.learned import default_prior


# ======================================================================== objects
def _name_object_id(name: str) -> int:
    """Stable object id of a problem outside the catalogue, from its name."""
    from legs_jax.core.keys import object_id_from_name  # jax: not at sweep start-up

    return int(object_id_from_name(name))


def _resolve_names(requested: Sequence[str], catalog) -> list[tuple[str, str, int]]:
    """(name, set, object_id) of set or object names, in catalogue order."""
    infos = list(catalog.objects())
    by_name = {i.name: i for i in infos}
    sets: OrderedDict[str, list] = OrderedDict()
    for i in infos:
        sets.setdefault(i.set, []).append(i)
    chosen: list = []
    for r in requested:
        if r in sets:
            chosen.extend(sets[r])
        elif r in by_name:
            chosen.append(by_name[r])
        else:
            known = list(sets) + list(by_name)
            near = difflib.get_close_matches(r, known, n=3)
            hint = f"; did you mean {', '.join(near)}?" if near else ""
            raise SweepError(
                f"unknown object or set '{r}' (sets: {', '.join(sets)}; "
                f"objects: {', '.join(by_name)}){hint}"
            )
    seen = set()
    out = []
    for i in chosen:
        if i.name not in seen:
            seen.add(i.name)
            out.append((i.name, i.set, int(i.object_id)))
    rank = {i.name: n for n, i in enumerate(infos)}
    out.sort(key=lambda x: rank[x[0]])
    return out


def _entry(
    name: str, set_: str, object_id: int, path: str | os.PathLike, source: str
) -> ObjectEntry:
    head = problem_mod.peek(path)  # ProblemFileError names the file and field
    T, P, K = head["shapes"]["robustness"]
    return ObjectEntry(
        name=name,
        set=set_,
        object_id=object_id,
        path=str(path),
        sha256=res.sha256_file(path),
        num_poses=int(P),
        num_grasps=int(K),
        num_trials=int(T),
        prior=problem_mod.prior_kind(head["meta"]),
        source=source,
    )


def _user_problems(paths: Sequence[str], catalog) -> list[ObjectEntry]:
    known = {}
    if catalog is not None:
        known = {i.name: i for i in catalog.objects()}
    entries = []
    for p in paths:
        pb = problem_mod.load(p)  # validates; ProblemFileError names file and field
        meta = pb.meta or {}
        if "object_id" in meta:
            oid = int(meta["object_id"])
        elif (
            pb.name in known
            and meta.get("set", known[pb.name].set) == known[pb.name].set
        ):
            oid = int(known[pb.name].object_id)
        else:
            oid = _name_object_id(pb.name)
        set_ = str(
            meta.get("set", known[pb.name].set if pb.name in known else "custom")
        )
        entries.append(_entry(pb.name, set_, oid, p, "user"))
    names = [e.name for e in entries]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SweepError(f"--problems: several files hold the object {dup[0]!r}")
    return entries


def _smoke_problems(names: Sequence[str], catalog, folder: Path) -> list[ObjectEntry]:
    """Synthetic problems at smoke size, named like the real objects."""
    known = {}
    if catalog is not None:
        known = {i.name: i for i in catalog.objects()}
    entries = []
    for name in names:
        info = known.get(name)
        oid = int(info.object_id) if info is not None else _name_object_id(name)
        set_ = info.set if info is not None else "synthetic"
        path = folder / f"{_safe(name)}.npz"
        if not path.is_file():
            pb = synthetic.make_problem(
                seed=oid,
                num_poses=SMOKE["num_poses"],
                num_grasps=SMOKE["num_grasps"],
                num_trials=SMOKE["trials"],
                name=name,
            )
            pb = dataclasses.replace(
                pb, meta={**pb.meta, "synthetic": True, "smoke": True}
            )
            problem_mod.save(pb, path)
        entries.append(_entry(name, set_, oid, path, "smoke"))
    return entries


_GENERATOR = "legs_jax.families:make_problem"


def _generated_problems(
    families: Sequence[tuple[str, Mapping[str, Any]]],
    requested: Sequence[str] | None,
    folder: Path,
    *,
    smoke: bool,
    generator: str = _GENERATOR,
) -> list[ObjectEntry]:
    """The problems an experiment generates (``GENERATED``: (name, keyword
    arguments of ``GENERATOR``), seeded and deterministic), written once into
    ``folder``; with ``smoke``, the first few at smoke size."""
    import importlib

    known = [n for n, _ in families]
    if requested:
        unknown = [r for r in requested if r not in known]
        if unknown:
            near = difflib.get_close_matches(unknown[0], known, n=3)
            hint = f"; did you mean {', '.join(near)}?" if near else ""
            raise SweepError(
                f"unknown generated problem '{unknown[0]}' (this experiment "
                f"generates: {', '.join(known)}){hint}"
            )
        families = [f for f in families if f[0] in requested]
    elif smoke:
        families = list(families)[: SMOKE["max_objects"]]
    module, _, attr = generator.partition(":")
    make = getattr(importlib.import_module(module), attr)
    entries = []
    for name, kwargs in families:
        kw = dict(kwargs)
        if smoke:
            kw.update(num_grasps=SMOKE["num_grasps"], num_trials=SMOKE["trials"])
            if "num_poses" in kw or "effective_poses" in kw:
                kw["num_poses"] = min(int(kw.get("num_poses", 8)), SMOKE["num_poses"])
                kw["effective_poses"] = min(
                    float(kw.get("effective_poses", 1.0)), kw["num_poses"]
                )
        path = folder / f"{_safe(name)}.npz"
        pb = make(name=name, **kw)
        if not path.is_file() or problem_mod.load(path) != pb:
            problem_mod.save(pb, path)
        entries.append(
            _entry(name, "generated", _name_object_id(name), path, "generated")
        )
    return entries


# ===================================================================== experiments
def _experiment_plan(
    name: str, a: argparse.Namespace, catalog, out: Path
) -> ExperimentPlan | None:

    mod = experiments.get(name)
    arms = _arms(mod.ARMS, a.methods, a.grid, getattr(a, "declared", set()))
    if not arms:
        return None
    trials = a.trials or (SMOKE["trials"] if a.smoke else mod.TRIALS)
    rollouts = a.rollouts or (SMOKE["rollouts"] if a.smoke else mod.ROLLOUTS)
    horizon = a.horizon or (SMOKE["horizon"] if a.smoke else mod.HORIZON)
    generated = tuple(getattr(mod, "GENERATED", ()))
    if a.problems:
        objects = _user_problems(a.problems, catalog)
    elif generated:
        objects = _generated_problems(
            generated,
            list(a.objects) if a.objects else None,
            out / ("_smoke_problems" if a.smoke else "_generated") / name,
            smoke=bool(a.smoke),
            generator=getattr(mod, "GENERATOR", _GENERATOR),
        )
    else:
        requested = list(a.objects) if a.objects else None
        if a.smoke:
            names = requested or list(mod.SMOKE_OBJECTS)[: SMOKE["max_objects"]]
            if catalog is not None:
                names = [n for n, _, _ in _resolve_names(names, catalog)]
            objects = _smoke_problems(names, catalog, out / "_smoke_problems")
        else:
            if catalog is None:
                raise SweepError(
                    "the object catalogue (precompute.catalog) is not available; "
                    "pass problem files with --problems"
                )
            resolved = _resolve_names(requested or list(mod.OBJECTS), catalog)
            source = getattr(a, "problem_source", None) or "shipped"
            if source == "built" and not a.overwrite:
                _refuse_other_source(name, out, source)
            objects = _catalog_problems(
                resolved,
                dry_run=bool(a.dry_run),
                prior=getattr(mod, "PRIOR", None),
                source=source,
            )
    plan = ExperimentPlan(
        name=name,
        description=mod.DESCRIPTION,
        objects=objects,
        arms=arms,
        trials=trials,
        rollouts=rollouts,
        horizon=horizon,
        record_every=mod.RECORD_EVERY,
        check_every=mod.CHECK_EVERY,
        check_methods=tuple(mod.CHECK_METHODS),
        active_set_methods=tuple(mod.ACTIVE_SET_METHODS),
        seed=a.seed,
        smoke=bool(a.smoke),
        extra={"rho_min": list(getattr(mod, "RHO_MIN", ()))},
    )
    _check_plan(plan)
    plan.chunks = plan_chunks(plan)
    return plan


def _arms(
    own_arms: Sequence[tuple[str, str, Mapping[str, Any]]],
    requested: Sequence[str] | None,
    grid: Mapping[str, Any] | None,
    declared: set[str] | frozenset[str] = frozenset(),
) -> list[Arm]:
    """The arms to run: the experiment's own, or those of the ``requested``
    methods (a method that no experiment declares, not in ``declared``, such as
    the user's own, runs with its defaults); with a ``grid``, each requested
    method that has all of its hyperparameters runs on it instead."""
    if not requested:
        return [make_arm(m, v, hp) for m, v, hp in own_arms]
    arms: list[Arm] = []
    if grid is not None:
        names = [_method(spec).defaults() for spec in requested]
        for g in grid:
            if not any(g in known for known in names):
                raise SweepError(
                    f"--grid: {g} is not a hyperparameter of "
                    f"{' or '.join(_method(x).name for x in requested)}"
                )
    for spec in requested:
        m = _method(spec)
        name = m.name
        if grid is not None and set(grid) <= set(m.defaults()):
            arms.append(make_arm(spec, "", grid))
            continue
        own = [make_arm(m, v, hp) for m, v, hp in own_arms if m == name]
        if not own and name not in declared:
            own = [make_arm(spec, "", {})]
        arms.extend(own)
    labels = [a.label for a in arms]
    if len(set(labels)) != len(labels):
        raise SweepError(f"--methods names a method twice: {', '.join(labels)}")
    order = {m: i for i, (m, _, _) in enumerate(own_arms)}
    arms.sort(key=lambda a: order.get(a.method, len(order)))
    return arms


class _ProblemsMissing(Exception):
    """Dry run: these catalogue problem files would be built first."""

    def __init__(self, names: Sequence[str]):
        super().__init__(" ".join(names))
        self.names = list(names)


def _missing_problems(names: Sequence[str], params=None) -> list[str]:
    """Catalogue objects whose problem file is missing or out of date."""
    return [i.name for i in precompute.out_of_date(list(names), params=params)]


def _refuse_other_source(name: str, out: Path, source: str) -> None:
    """Refuse, before any problem is built, to add to results that were made from
    problem files of another source (the shipped set's files never equal files
    built from the meshes: the encodings differ)."""
    import json

    mf = out / name / "manifest.json"
    try:
        with open(mf) as fh:
            files = json.load(fh).get("problem_files") or {}
    except (OSError, json.JSONDecodeError):
        return
    other = sorted(
        {str(f.get("source", "built")) for f in files.values()} - {source, "user"}
    )
    if other:
        raise SweepError(
            f"{out / name} holds results made from the {other[0]} problem files; "
            f"--problem-source {source} would run on other files. Run with "
            f"--problem-source {other[0]} to use those results, or add --overwrite "
            "to recompute them (or --out DIR for another folder)"
        )


def _catalog_problems(
    resolved: Sequence[tuple[str, str, int]],
    *,
    dry_run: bool = False,
    prior: str | None = None,
    source: str = "shipped",
) -> list[ObjectEntry]:
    """The problem files of catalogue objects: the shipped set's
    (``source="shipped"``, :mod:`precompute.problemset`), or files built from the
    meshes on this machine (``"built"``, made when missing); ``prior``: the prior
    they carry (an experiment's ``PRIOR``; None: the default one)."""
    params = None
    if prior is not None:
        try:
            params = precompute.BuildParams(prior=prior).check()
        except PrecomputeError as e:
            raise SweepError(str(e)) from None
    names = [n for n, _, _ in resolved]
    if source == "shipped":
        paths = problemset.paths(names, prior or default_prior())
    else:
        if dry_run:
            missing = _missing_problems(names, params)
            if missing:
                raise _ProblemsMissing(missing)
        paths = precompute.ensure(names, params=params)
    return [_entry(n, s, oid, paths[n], source) for n, s, oid in resolved]
