"""The stream with only t, q and currents: causal derivatives with a stated delay, the problem's column mapping,
and parameters within their standard errors of the batch fit on the same data."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ident_opt.adaptation.estimator import batch_theta
from ident_opt.adaptation.lines import LineParser, Mapping
from ident_opt.adaptation.start import offline_start
from ident_opt.arm.planar import RIGID
from ident_opt.data.dataset import chronological_split
from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError
from ident_opt.fitting.fit import finish
from ident_opt.fitting.stats import Stats
from ident_opt.numerics.causal import CausalDerivatives, derivative_kernels
from ident_opt.numerics.derivatives import REST

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "problems" / "tudor_2dof.toml"


def test_kernels_differentiate_with_the_stated_delay():
    dt = 0.01
    k1, k2, delay = derivative_kernels(dt, 15.0)
    assert k2.size == 2 * delay + 1 and k1.size == k2.size
    t = np.arange(k2.size) * dt
    w = 2 * np.pi * 0.7  # a slow motion, well inside the pass band
    q = np.sin(w * t + 0.3)
    centre = t[delay]
    assert k1 @ q == pytest.approx(w * np.cos(w * centre + 0.3), rel=2e-3)
    assert k2 @ q == pytest.approx(-(w**2) * np.sin(w * centre + 0.3), rel=2e-3)
    assert abs(k1 @ (5 + 0 * t)) < 1e-12 and abs(k2 @ (t * 3.0)) < 1e-9  # constant → 0; ramp → no acceleration


def test_causal_derivatives_at_rest_are_exactly_zero_and_restart_on_gaps():
    d = CausalDerivatives(15.0)
    outs = [d.push({"t": 0.01 * k, "q1": 1.9024, "q2": -0.5}) for k in range(60)]
    done = [o for o in outs if o is not None]
    assert done and all(o["dq1"] == 0.0 and o["ddq1"] == 0.0 for o in done)
    assert done[0]["t"] == pytest.approx(0.01 * d.delay)  # the sample `delay` steps back
    assert d.lost == d.delay * 2 and REST > 0
    assert d.push({"t": 5.0, "q1": 1.0, "q2": 0.0}) is None and d.restarts == 0  # a long step is held back …
    assert d.push({"t": 5.01, "q1": 1.0, "q2": 0.0}) is None and d.restarts == 1  # … and is a gap: a new window


def test_mapping_and_conversions_apply_to_the_stream():
    mapping = Mapping({"q1": "pos1", "q2": "pos2", "t": "time", "tau1": "m1", "tau2": "m2"}, {"q1": (-1.0, 0.5)})
    p = LineParser(mapping=mapping)
    assert p.parse("time,pos1,pos2,m1,m2,other\n") is None
    s = p.parse("0.5,2.0,3.0,1.5,-1.5,x\n")
    assert s == {"t": 0.5, "q1": -1.5, "q2": 3.0, "tau1": 1.5, "tau2": -1.5}
    j = LineParser(mapping=mapping)
    assert j.parse('{"time": 0.5, "pos1": 2.0, "pos2": 3.0}') == {"t": 0.5, "q1": -1.5, "q2": 3.0}
    with pytest.raises(InputError):
        LineParser(mapping=mapping).parse("time,pos2\n")  # q1 unmapped in the header
    with pytest.raises(InputError):  # no dq/ddq and no t: derivatives cannot be estimated
        LineParser().parse("q1,q2,tau1,tau2\n")
    headerless = LineParser(mapping=Mapping({"t": 0, "q1": 2, "q2": 3, "i1": 8, "i2": 9}, header=False))
    headerless.current_to_torque = (2.0, 3.0)
    s = headerless.parse("0.1,9,1.0,2.0,9,9,9,9,0.5,0.25\n")
    assert s == {"t": 0.1, "q1": 1.0, "q2": 2.0, "tau1": 1.0, "tau2": 0.75}


def test_exp2_stream_with_t_q_i_only_matches_the_batch_fit(physical_problem, exp1, tmp_path):
    """Offline start on exp1's first 70 %; exp2 streamed as t, q1, q2, i1, i2 (the problem maps them by name);
    the final parameters against the batch bounded LS on the same statistics with the batch loader's
    zero-phase derivatives (speeds below `REST` as rest in both), within one standard error each."""
    raw = np.loadtxt(ROOT / "data" / "merit" / "exp2.csv", delimiter=",")
    stream = tmp_path / "exp2_tqi.csv"
    columns = {"t": 0, "q1": 2, "q2": 3, "i1": 8, "i2": 9}
    lines = ["t,q1,q2,i1,i2"] + [",".join(repr(float(row[c])) for c in columns.values()) for row in raw]
    stream.write_text("\n".join(lines) + "\n")
    final_path = tmp_path / "final.json"
    cmd = [sys.executable, "-m", "ident_opt", "online", "--problem", str(PROBLEM), "--stream", "--model", "pbr"]
    with stream.open() as stdin:
        done = subprocess.run(
            [*cmd, "--final", str(final_path), "--snapshot-every", "0", "--no-contact"],  # every sample learnt
            stdin=stdin,
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=600,
        )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "ident-opt online: cpbr starts from the constrained fit (" in done.stderr  # the recommended fit, why
    final = json.loads(final_path.read_text())["final"]
    assert final["derivatives"]["estimated"] and final["derivatives"]["delay_samples"] > 0
    assert final["updates"] + final["outliers"] + final["derivatives"]["lost"] == len(raw)
    assert final["outliers"] < 10
    records = [json.loads(x) for x in done.stdout.splitlines()]
    assert all(isinstance(r.get("extrapolating", False), bool) for r in records)

    spec = dataclasses.replace(
        physical_problem.data,
        columns={k: v for k, v in physical_problem.data.columns.items() if k in columns},
        conversions={},
        rest_velocity="as_read",  # the stream's own rest rule (REST) is applied below, as the stream applies it
    )
    exp2 = load_dataset(ROOT / "data" / "merit" / "exp2.csv", spec, physical_problem.robot)
    assert exp2.cutoff_hz == final["derivatives"]["cutoff_hz"]
    tr, _ = chronological_split(exp1.n, physical_problem.split.train_fraction)
    train = exp1.subset(tr)
    dq = np.where(np.abs(exp2.dq) < REST, 0.0, exp2.dq)
    stats = Stats.from_data(RIGID, train.q, train.dq, train.ddq, train.tau)
    stats = stats + Stats.from_data(RIGID, exp2.q, dq, exp2.ddq, exp2.tau)
    start = offline_start("pbr", physical_problem, train)
    pi = batch_theta(start.estimator, stats)
    se = finish(stats, RIGID, pi, np.ones(2), "bounded").se
    online = np.array([final["parameters"][n] for n in RIGID.names])
    at_bound = (online == 0) & (pi == 0)
    z = np.abs(online - pi)[~at_bound] / se[~at_bound]
    assert z.max() <= 1.0, dict(zip(np.array(RIGID.names)[~at_bound], np.round(z, 2)))
