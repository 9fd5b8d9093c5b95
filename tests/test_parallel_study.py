"""The study engine's chunks and seeds, its executors (threads, Dask), the sweep command, and the
pieces made faster for it: the joint draw of the flicker noise, channel selection in the batch
generator, window means of wavelet thresholding."""

from __future__ import annotations

import json
import math
import sys
from typing import Any, cast

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from northfinder.cli import main
from northfinder.driver.protocol.units import DPSH, UG
from northfinder.firmware_sim import error_terms as et
from northfinder.firmware_sim.batch import simulate_windows
from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.batch_solve import chunk_errors
from northfinder.host.denoise import METHODS, denoise, denoised_mean, wavelet_denoise_mean
from northfinder.host.distributed import (
    DistributedError,
    dask_executor,
    max_local_workers,
    parse_dask_address,
)
from northfinder.host.errors import HostConfigError
from northfinder.host.montecarlo import (
    RunRequest,
    StudySettings,
    chunk_runs,
    chunk_tasks,
    local_executor,
    monte_carlo,
    monte_carlo_many,
)
from northfinder.host.plan import Plan
from northfinder.simwindows import SimulatedWindows

# 10 s windows at 200 Hz: 65 runs a chunk, so 150 runs make three chunks, the last one short.
PLAN = Plan((0.0, 180.0), 10.0, denoise="wavelet-soft")
SETTINGS = StudySettings()
RUNS = 150


@pytest.fixture(scope="module")
def generator():
    return SimulatedWindows(load_spec("paper-rlg"))


@pytest.fixture(scope="module")
def serial(generator):
    return monte_carlo(generator, PLAN, SETTINGS, RUNS, 5)


# ----------------------------------------------------------------------------------------------
# Chunks and seeds
# ----------------------------------------------------------------------------------------------


def test_chunks_are_fixed_by_the_plan_not_by_the_workers(generator):
    assert chunk_runs(PLAN, SETTINGS) == 65
    assert [t.runs for t in chunk_tasks(generator, PLAN, SETTINGS, RUNS, 5)] == [65, 65, 20]
    assert chunk_runs(Plan((0.0, 180.0), 1000.0), SETTINGS) == 1  # at least one run


def test_chunk_k_draws_from_child_k_of_the_seed_sequence(generator, serial):
    """The seeding as documented, rebuilt here without the engine: chunk k is the generator's
    draw with child k of SeedSequence(seed), azimuths first."""
    children = np.random.SeedSequence(5).spawn(3)
    for k, (start, size) in enumerate([(0, 65), (65, 65), (130, 20)]):
        rng = np.random.default_rng(children[k])
        az = rng.uniform(0.0, 360.0, size)
        request = RunRequest(PLAN, az, 34.0, 0.0, 0.0, 200.0, 120.0, 0.0, (0, 1, 3, 4))
        batch = generator(request, rng)
        errors = chunk_errors(
            batch.gyro_rps,
            batch.accel_mps2,
            batch.table_deg,
            batch.azimuth_deg,
            34.0,
            denoise_method="wavelet-soft",
        )
        assert_array_equal(serial[start : start + size], errors)


def test_results_are_identical_whatever_the_number_of_threads(generator, serial):
    for workers in (1, 2, 3):
        with local_executor(workers) as ex:
            assert_array_equal(monte_carlo(generator, PLAN, SETTINGS, RUNS, 5, executor=ex), serial)


def test_whole_chunks_of_a_shorter_study_begin_a_longer_one(generator, serial):
    assert_array_equal(monte_carlo(generator, PLAN, SETTINGS, 130, 5), serial[:130])
    other = monte_carlo(generator, PLAN, SETTINGS, 130, 6)
    assert not np.any(other == serial[:130])  # another seed, other draws


def test_many_studies_give_what_each_gives_alone(generator, serial):
    level = StudySettings(tilt="level")
    pair = Plan((0.0, 90.0, 180.0), 5.0, method="pairwise")
    with local_executor(2) as ex:
        got = monte_carlo_many(
            [(generator, PLAN, SETTINGS, RUNS, 5), (generator, pair, level, 40, 2)], executor=ex
        )
    assert_array_equal(got[0], serial)
    assert_array_equal(got[1], monte_carlo(generator, pair, level, 40, 2))
    assert got[1].shape == (40, 2)


def test_bad_runs_seeds_and_workers_are_refused(generator):
    runs: Any
    for runs in (1, 2.5, True):
        with pytest.raises(HostConfigError, match="runs"):
            monte_carlo(generator, PLAN, SETTINGS, runs, 0)
    with pytest.raises(HostConfigError, match="seed"):
        monte_carlo(generator, PLAN, SETTINGS, 10, -1)
    with pytest.raises(HostConfigError, match="workers"), local_executor(0):
        pass


# ----------------------------------------------------------------------------------------------
# Dask
# ----------------------------------------------------------------------------------------------


def test_a_local_dask_cluster_gives_the_results_of_one_process(generator, serial):
    distributed = pytest.importorskip("distributed")
    with (
        distributed.LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=False,
            protocol="tcp://",  # real messages (pickled chunks), on the loopback interface
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        ex = client.get_executor()
        assert_array_equal(monte_carlo(generator, PLAN, SETTINGS, RUNS, 5, executor=ex), serial)
        # Both workers took chunks.
        assert len(client.run(lambda: 1)) == 2


def test_dask_addresses_are_checked_and_an_absent_scheduler_is_one_error(monkeypatch):
    assert parse_dask_address("local:2") == ("local", 2)
    assert parse_dask_address("tcp://10.1.2.3:8786") == ("remote", "tcp://10.1.2.3:8786")
    assert parse_dask_address("tls://scheduler.lab:8786")[0] == "remote"
    limit = max_local_workers()
    assert parse_dask_address(f"local:{limit}") == ("local", limit)
    for bad in ("local:0", f"local:{limit + 1}", "local:1000", "local:" + "9" * 40):
        with pytest.raises(HostConfigError, match=rf"local:N takes 1 to {limit} worker processes"):
            parse_dask_address(bad)
    for bad in ("local:1000", "local:0", "local:-1", "local:junk"):
        assert main(["study", "--dask", bad]) == 2
    for bad in ("local:x", "tcp://host", "tcp://host:99999", "http://h:1", "h:8786", ""):
        with pytest.raises(HostConfigError, match="tcp://HOST:PORT"):
            parse_dask_address(bad)
    pytest.importorskip("distributed")
    # A port on the loopback interface where nothing listens.
    with pytest.raises(DistributedError, match=r"cannot reach tcp://127\.0\.0\.1:9"):
        with dask_executor("tcp://127.0.0.1:9", timeout_s=1.0):
            pass
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(HostConfigError, match=r"pip install 'northfinder\[dask\]'"):
        with dask_executor("local:1"):
            pass


def test_cli_refuses_a_bad_cluster_address_as_a_usage_error(capsys):
    assert main(["study", "--dask", "8786", "--runs", "10"]) == 2
    assert "--dask: expected a scheduler address tcp://HOST:PORT" in capsys.readouterr().err
    assert main(["study", "--dask", "local:2", "--workers", "2"]) == 2
    assert main(["sweep", "--workers", "0"]) == 2


# ----------------------------------------------------------------------------------------------
# The sweep command
# ----------------------------------------------------------------------------------------------


def _json(capsys, argv):
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_sweep_rows_are_the_studies_of_the_same_seed(capsys):
    sweep = _json(
        capsys,
        [
            "sweep", "--sensors", "paper-rlg,fog-0.08", "--latitudes", "10,50",
            "--positions", "0,180", "--positions", "0,90,180,270", "--windows", "5",
            "--runs", "70", "--seed", "3", "--workers", "2", "--json",
        ],
    )  # fmt: skip
    studies = sweep["studies"]
    assert len(studies) == 2 * 2 * 2
    assert [(s["sensor"], s["latitude_deg"]) for s in studies[:3]] == [
        ("paper-rlg", 10.0),
        ("paper-rlg", 10.0),
        ("paper-rlg", 50.0),
    ]
    for s in (studies[1], studies[6]):
        alone = _json(
            capsys,
            [
                "study", "--sensor", s["sensor"], "--latitude", str(s["latitude_deg"]),
                "--positions", ",".join(map(str, s["plan"]["positions_deg"])), "--window", "5",
                "--runs", "70", "--seed", "3", "--workers", "1", "--json",
            ],
        )  # fmt: skip
        assert alone["results"] == s["results"]
        assert alone["plan"] == s["plan"]
    # The physics still holds in every row: no RMSE below the white-noise bound.
    for s in studies:
        r = s["results"][0]
        assert r["rmse_deg"] > r["bound_deg"] * (1 - 4 * r["rmse_rel_se"])


@pytest.mark.slow
@pytest.mark.subprocess
def test_sweep_on_a_local_dask_cluster_of_processes_gives_the_threaded_results(capsys):
    args = ["sweep", "--sensors", "paper-rlg", "--plan", "paper-30deg-sweep", "--windows", "2"]
    args += ["--runs", "60", "--json"]
    threaded = _json(capsys, [*args, "--workers", "2"])
    on_dask = _json(capsys, [*args, "--dask", "local:2"])
    assert on_dask["studies"] == threaded["studies"]
    assert len(threaded["studies"][0]["results"]) == 7  # pairwise: one row per pair


# ----------------------------------------------------------------------------------------------
# The flicker noise drawn jointly
# ----------------------------------------------------------------------------------------------


class _BasisDraws:
    """Stands in for a generator: hands out the columns of an identity matrix as the draws,
    so that the output of a linear sampler is its own matrix (column j: the response to draw j)."""

    def __init__(self, n):
        self.eye, self.used = np.eye(n), 0

    def standard_normal(self, shape):
        rows, d = shape
        out = self.eye[:rows, self.used : self.used + d]
        self.used += d
        return out


def _stepped_law(m):
    """Mean matrix and covariance of slow_noise_steps over m steps (sums, then the components)."""
    k = et.FLICKER_TAUS_S.size
    w = np.zeros((m, k + 1, m * k))
    w[:, :k, :] = np.eye(m * k).reshape(m, k, m * k)
    f, _, s, _ = et.slow_noise_steps(w, np.zeros((k, m * k)), np.zeros(m * k))
    noise = np.vstack([f, s])
    f0, _, s0, _ = et.slow_noise_steps(np.zeros((m, k + 1, k)), np.eye(k), np.zeros(k))
    return np.vstack([f0, s0]), noise @ noise.T


@pytest.mark.parametrize("m", [1, 7, 300])
def test_the_joint_flicker_draw_has_the_law_of_the_steps(m):
    """Exactly (to rounding): the same mean from the start state and the same covariance, also
    across the pieces of 256 steps a long window is drawn in; fewer draws than innovations."""
    k = et.FLICKER_TAUS_S.size
    mean, cov = _stepped_law(m)
    pieces = [256] * (m // 256) + ([m % 256] if m % 256 else [])
    d = sum(size - 1 + k for size in pieces)  # draws: m - 1 + K a piece
    draws = _BasisDraws(d)
    f, walks, s, walk = et.slow_noise_window(
        cast(np.random.Generator, draws), np.zeros((k, d)), np.zeros(d), m, with_walk=False
    )
    assert draws.used == d and (d < m * k or m == 1)
    noise = np.vstack([f, s])  # (m + K, d): the response to every draw
    assert_allclose(noise @ noise.T, cov, rtol=0, atol=1e-12 * cov.max())
    zeros = cast(np.random.Generator, _ZeroDraws())
    f0, _, s0, _ = et.slow_noise_window(zeros, np.eye(k), np.zeros(k), m, with_walk=False)
    assert_allclose(np.vstack([f0, s0]), mean, rtol=0, atol=1e-13)
    assert np.all(walks == 0) and np.all(walk == 0)


class _ZeroDraws:
    def standard_normal(self, shape):
        return np.zeros(shape)


def test_the_joint_draw_keeps_the_walk_of_the_steps():
    rng = np.random.default_rng(3)
    k = et.FLICKER_TAUS_S.size
    _, walks, _, walk = et.slow_noise_window(rng, np.zeros((k, 4000)), np.zeros(4000), 50)
    # A unit random walk on the 0.1 s grid: variance 0.1 per step.
    assert_allclose(walks.var(axis=1), 0.1 * np.arange(1, 51), rtol=0.1)
    assert_array_equal(walk, walks[-1])


# ----------------------------------------------------------------------------------------------
# Channels of the batch generator
# ----------------------------------------------------------------------------------------------


def test_channels_left_out_are_nan_and_the_others_keep_their_noise():
    spec = load_spec("ideal").with_values({"gyro.arw_dpsh": 0.0015, "accel.vrw_ug_rthz": 10.0})
    b = simulate_windows(
        spec, Truth(), [0, 180], 10.0, n_runs=40, rng=np.random.default_rng(3), channels=[4, 0]
    )
    assert np.isnan(b.gyro_rps[..., 1:]).all() and np.isnan(b.accel_mps2[..., [0, 2]]).all()
    g = b.gyro_rps[..., 0] - b.gyro_rps[..., 0].mean(axis=2, keepdims=True)
    a = b.accel_mps2[..., 1] - b.accel_mps2[..., 1].mean(axis=2, keepdims=True)
    assert_allclose(g.std(), 0.0015 * DPSH * math.sqrt(200.0), rtol=0.01)
    assert_allclose(a.std(), 10.0 * UG * math.sqrt(200.0), rtol=0.01)
    # The noise-free part is that of all channels.
    quiet = load_spec("ideal")
    some = simulate_windows(
        quiet, Truth(30.0), [0, 90], 1.0, n_runs=2, rng=np.random.default_rng(1), channels=[1, 5]
    )
    every = simulate_windows(
        quiet, Truth(30.0), [0, 90], 1.0, n_runs=2, rng=np.random.default_rng(1)
    )
    assert_array_equal(some.gyro_rps[..., 1], every.gyro_rps[..., 1])
    assert_array_equal(some.accel_mps2[..., 2], every.accel_mps2[..., 2])
    bad: Any
    for bad in ([], [6], [-1], ["x"], [1.5]):
        with pytest.raises(SimConfigError, match="channels"):
            simulate_windows(
                quiet, Truth(), [0], 1.0, n_runs=1, rng=np.random.default_rng(), channels=bad
            )


# ----------------------------------------------------------------------------------------------
# Window means of the denoising methods
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", [m for m in METHODS if METHODS[m].has_mean])
@pytest.mark.parametrize(
    ("n", "options"),
    [(2000, {}), (2000, {"extension": "symmetric"}), (1999, {}), (2048, {"level": 5})],
)
def test_denoised_means_are_the_means_of_the_denoised_signals(method, n, options):
    rng = np.random.default_rng(8)
    t = np.arange(n) / 200.0
    x = 1e-4 * (
        rng.standard_normal((3, 2, n)) + np.sin(7 * t) + (rng.random((3, 2, n)) < 0.01) * 40
    )
    if method == "wavelet-003":
        options = {**options, "mu": 0.2e8}  # its mu has the unit 1/w^2
    full = denoise(x, method, axis=-1, **options).mean(axis=-1)
    assert_allclose(denoised_mean(x, method, axis=-1, **options), full, rtol=0, atol=1e-17)
    along = denoised_mean(np.moveaxis(x, -1, 0), method, axis=0, **options)
    assert_allclose(along, full, rtol=0, atol=1e-17)


def test_denoised_mean_checks_what_the_transform_would():
    x = np.ones((2, 2000))
    with pytest.raises(HostConfigError, match="mode"):
        wavelet_denoise_mean(x, "median")
    with pytest.raises(HostConfigError, match="threshold must be finite"):
        denoised_mean(x, "wavelet-soft", value=-1.0)
    with pytest.raises(HostConfigError, match="alpha"):
        denoised_mean(x, "wavelet-2p", alpha=2.0)
    with pytest.raises(HostConfigError, match="bad options"):
        denoised_mean(x, "wavelet-hard", window=3)
    x[0, 5] = np.nan
    with pytest.raises(HostConfigError, match="non-finite"):
        denoised_mean(x, "wavelet-soft")
