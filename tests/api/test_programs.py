"""Compiled programs kept on disk, and the point buckets that bound how many there are
(`jaxpose.api._programs`, `solve_pnp`'s padding)."""

import functools
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.api import _pnp, _programs
from jaxpose.api._programs import CACHE_ENV, Program, bucket_points, cache_dir

K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])


def _problem(n: int, seed: int, noise: float = 0.5):
    rng = np.random.default_rng(seed)
    obj = rng.uniform(-60, 60, (n, 3))
    R = np.asarray(jp.rotvec_to_matrix(rng.normal(0, 0.4, 3)))
    t = np.array([rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(350, 600)])
    X = obj @ R.T + t
    img = X[:, :2] / X[:, 2:] * 800 + [320, 240] + rng.normal(0, noise, (n, 2))
    return obj, img


def _tiny(x):
    """A program that calls LAPACK (a linear solve): loading one in a new process needs
    the LAPACK kernels set up first."""
    return jnp.linalg.solve(x @ x.T + jnp.eye(3), x[:, 0])


def test_buckets():
    assert [bucket_points(n) for n in (3, 8, 9, 16, 17, 40, 64, 65, 1024)] == [
        8,
        8,
        16,
        16,
        32,
        64,
        64,
        128,
        1024,
    ]
    assert bucket_points(1025) == 2048 and bucket_points(3000) == 4096


def test_cache_location_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "here"))
    assert cache_dir() == tmp_path / "here"
    for off in ("off", "0", "", "false"):
        monkeypatch.setenv(CACHE_ENV, off)
        assert cache_dir() is None
    monkeypatch.delenv(CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "jaxpose"


def test_programs_are_stored_loaded_and_rebuilt(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    x = jnp.arange(9.0).reshape(3, 3) / 7
    first = Program(_tiny, "tests.tiny")
    want = first(x)
    assert (first.compiled, first.loaded) == (1, 0)
    files = list((tmp_path / "programs").rglob("*.bin"))
    assert len(files) == 1
    again = Program(_tiny, "tests.tiny")  # as a new process would: from disk
    np.testing.assert_array_equal(again(x), want)
    assert (again.compiled, again.loaded) == (0, 1)
    again(x)
    assert (again.compiled, again.loaded) == (0, 1)  # kept in the process
    other = Program(_tiny, "tests.tiny")  # another shape: another program
    other(jnp.ones((3, 4)))
    assert other.compiled == 1
    # a damaged file is compiled again and replaced, never used
    files[0].write_bytes(files[0].read_bytes()[:100])
    broken = Program(_tiny, "tests.tiny")
    np.testing.assert_array_equal(broken(x), want)
    assert (broken.compiled, broken.loaded) == (1, 0)
    assert Program(_tiny, "tests.tiny").executable(x) is not None
    # another build (jaxpose's sources, jax, the machine, XLA_FLAGS): a new folder, its
    # own programs; the folders of the builds used longest ago removed, the
    # `KEEP_BUILDS` most recent kept (two environments on one machine keep theirs)
    old = files[0].parent
    os.utime(old, (1e9, 1e9))  # used long ago
    for k in range(1, _programs.KEEP_BUILDS + 1):
        monkeypatch.setattr(_programs, "_FINGERPRINT", f"build-{k}")
        rebuilt = Program(_tiny, "tests.tiny")
        rebuilt(x)
        assert (rebuilt.compiled, rebuilt.loaded) == (1, 0)
        os.utime(tmp_path / "programs" / f"build-{k}", (1e9 + k, 1e9 + k))
        assert old.exists() == (k < _programs.KEEP_BUILDS)
    kept = sorted(p.name for p in (tmp_path / "programs").iterdir())
    assert kept == [f"build-{k}" for k in range(1, _programs.KEEP_BUILDS + 1)]


def test_a_command_s_programs_are_loaded_ahead(monkeypatch, tmp_path):
    """`remember` lists the program files a process used under a command's name;
    `prefetch` in a later process loads them in a background thread, and the `Program`
    that needs one takes it from there (loaded once, not compiled, the same answers)."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    monkeypatch.setattr(_programs, "_USED", [])
    monkeypatch.setattr(_programs, "_SINCE", {})
    monkeypatch.setattr(_programs, "_PREFETCHED", {})
    x = jnp.arange(9.0).reshape(3, 3) / 7
    first = Program(_tiny, "tests.tiny-ahead")
    want = first(x)
    _programs.remember("tests-command")
    folder = next((tmp_path / "programs").iterdir())
    listed = (folder / "used-tests-command.txt").read_text().split()
    assert listed == [p.name for p in folder.glob("*.bin")]
    # as a new process would: nothing used yet, the command's programs loaded ahead
    monkeypatch.setattr(_programs, "_USED", [])
    _programs.prefetch("tests-command")
    pending = dict(_programs._PREFETCHED)
    assert [p.name for p in pending] == listed
    again = Program(_tiny, "tests.tiny-ahead")
    np.testing.assert_array_equal(again(x), want)
    assert (again.compiled, again.loaded) == (0, 1)
    assert not _programs._PREFETCHED  # taken by the program that needed it
    assert all(f.done() for f in pending.values())
    # a program already used in this process is not loaded again
    _programs.prefetch("tests-command")
    assert not _programs._PREFETCHED
    # another program's file under the same name: its own key decides, never the file's
    monkeypatch.setattr(_programs, "_USED", [])
    _programs.prefetch("tests-command")
    other = Program(_tiny, "tests.tiny-ahead-other")
    other(x)
    assert (other.compiled, other.loaded) == (1, 0)
    _programs.prefetch("no-such-command")  # no list yet: nothing
    assert not any(p.name not in listed for p in _programs._PREFETCHED)


def test_cache_off_keeps_nothing(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, "off")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    p = Program(_tiny, "tests.tiny-off")
    p(jnp.eye(3))
    assert p.compiled == 1 and not any(tmp_path.iterdir())


def test_a_new_process_loads_instead_of_compiling(tmp_path):
    """Two fresh processes: the first compiles and stores, the second loads (a program
    that calls LAPACK, which crashed when loaded before LAPACK was set up)."""
    script = textwrap.dedent(
        """
        import jax, jax.numpy as jnp
        jax.config.update("jax_enable_x64", True)
        from jaxpose.api._programs import Program
        from tests.api.test_programs import _tiny
        p = Program(_tiny, "tests.tiny-process")
        y = p(jnp.arange(9.0).reshape(3, 3) / 7)
        print(p.compiled, p.loaded, repr(float(y.sum())))
        """
    )
    env = dict(os.environ, **{CACHE_ENV: str(tmp_path)})
    root = os.path.dirname(os.path.dirname(os.path.dirname(__file__)))

    def run():
        out = subprocess.run(
            [sys.executable, "-c", script], env=env, cwd=root, capture_output=True, text=True
        )
        assert out.returncode == 0, out.stderr
        return out.stdout.split()

    first, second = run(), run()
    assert first[:2] == ["1", "0"] and second[:2] == ["0", "1"]
    assert first[2] == second[2]


def _wavy(x, y):
    return jnp.sin(x) * y + jnp.cos(x * y)


def test_a_program_stored_beside_jax_persistent_cache_loads_and_runs(tmp_path):
    """JAX's persistent compilation cache on in every process: the first (program store
    off) fills it, the second stores the program, the third loads and runs it. A program
    stored from an executable that JAX's cache handed back lacked its machine code
    ("Function ... not found" when run). Then such a file is written on purpose (the
    store taking JAX's cached executable): the next process finds that it cannot run,
    compiles it again and replaces it, and gives the right answer."""
    script = textwrap.dedent(
        f"""
        import sys
        import jax, jax.numpy as jnp
        jax.config.update("jax_compilation_cache_dir", {str(tmp_path / "xla")!r})
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
        from jaxpose.api import _programs
        from tests.api.test_programs import _wavy
        if sys.argv[1] == "cached":  # the store as it was: JAX's cached executable kept
            _programs._compile = lambda lowered, fresh: lowered.compile(
                compiler_options=_programs.compiler_options()
            )
        p = _programs.Program(_wavy, "tests.wavy-process-" + sys.argv[2])
        y = p(jnp.arange(5.0), jnp.ones(5))
        print(p.compiled, p.loaded, repr(float(y.sum())))
        """
    )
    root = os.path.dirname(os.path.dirname(os.path.dirname(__file__)))

    def run(store: str, how: str = "fresh", name: str = "a"):
        env = dict(os.environ, **{CACHE_ENV: store})
        out = subprocess.run(
            [sys.executable, "-c", script, how, name],
            env=env,
            cwd=root,
            capture_output=True,
            text=True,
        )
        assert out.returncode == 0, out.stderr
        return out.stdout.split()

    programs = str(tmp_path / "programs")
    warm = run("off")
    stored, loaded = run(programs), run(programs)
    assert stored[:2] == ["1", "0"] and loaded[:2] == ["0", "1"]
    assert warm[2] == stored[2] == loaded[2]
    # a stored program that cannot run: compiled again, replaced
    run("off", name="b")
    bad = run(programs, "cached", "b")
    mended, again = run(programs, name="b"), run(programs, name="b")
    assert bad[:2] == ["1", "0"] and mended[:2] == ["1", "1"]
    # (the replacement, compiled where the broken program was loaded, may be broken or
    # unreadable too: then the next process mends it again; either way the answer is
    # right)
    assert again[:2] in (["0", "1"], ["1", "1"], ["1", "0"])
    assert bad[2] == mended[2] == again[2] == warm[2]


@pytest.mark.parametrize("n", [4, 11, 23])
def test_padded_points_give_the_unpadded_answer(n):
    """`solve_pnp` pads `n` to its bucket (masked): the answer is `solve`'s on the
    unpadded problem (whose best roots are accepted: no fallback compiled; values only, as
    `solve_pnp` computes)."""
    obj, img = _problem(n, seed=n)
    ok, rvec, tvec = jp.solve_pnp(obj, img, K)
    unpadded = functools.partial(jp.solve, options=jp.Options(fallback=False, derivative=False))
    sol = jax.jit(unpadded)(jp.camera_matrix(K), obj, img)
    assert ok and bool(sol.accepted)
    np.testing.assert_allclose(tvec[:, 0], np.asarray(sol.pose.t), rtol=1e-8, atol=1e-8)
    R = np.asarray(jp.rotvec_to_matrix(rvec[:, 0]))
    np.testing.assert_allclose(R, np.asarray(sol.pose.R), atol=1e-9)


def test_every_n_from_4_to_40_compiles_one_program_per_bucket():
    """Solving problems of every size from 4 to 40 points runs four programs (buckets 8,
    16, 32, 64): XLA compiles at most those four (fewer when the shared test cache already
    holds some), and a second pass over every size compiles nothing."""
    first_problems = [_problem(n, seed=100 + n) for n in range(4, 41)]
    second_problems = [_problem(n, seed=200 + n) for n in range(4, 41)]
    compiles: list[str] = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiles.append(event)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        before = _programs_in_use()
        for obj, img in first_problems:
            ok, _, _ = jp.solve_pnp(obj, img, K)
            assert ok, len(obj)
        programs = _programs_in_use() - before
        first_pass = len(compiles)
        for obj, img in second_problems:
            jp.solve_pnp(obj, img, K)
        assert len(compiles) == first_pass  # nothing new
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert programs <= 4
    assert first_pass <= 4


def test_thresholds_and_tolerances_compile_nothing():
    """The acceptance thresholds and the degeneracy tolerances are a program's values,
    not its structure: `solve_pnp` with other values runs the programs it already holds
    (no XLA compile), and the values take effect (an image area no triplet reaches leaves
    every triplet degenerate: no pose; the default finds it). A fixed threshold is
    another structure than the adaptive one (`None`), but its value is not."""
    key = _pnp._stages
    assert key(jp.Options(threshold=2.0)) == key(jp.Options(threshold=30.0))
    assert key(jp.Options(min_area=1.0, rel_threshold=0.5)) == key(jp.Options())
    assert key(jp.Options(threshold=2.0)) != key(jp.Options())
    obj, img = _problem(12, seed=7)
    compiles: list[str] = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiles.append(event)

    assert jp.solve_pnp(obj, img, K, min_area=1e12)[0] is False  # every rung runs
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        before = _programs_in_use()
        ok, _, tvec = jp.solve_pnp(obj, img, K, rel_threshold=0.05, collinear_tol=1e-3)
        assert ok and np.allclose(tvec, jp.solve_pnp(obj, img, K)[2])
        assert jp.solve_pnp(obj, img, K, min_area=1e13)[0] is False
        assert not compiles and _programs_in_use() == before
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)


def _programs_in_use() -> int:
    """Executables held by `solve_pnp`'s programs in this process."""
    return sum(len(p._memo) for p in _programs._PROGRAMS.values())


def test_the_programs_compiler_options_give_the_default_answers():
    """`Program` compiles with `compiler_options()` (XLA:CPU's element-wise emitters):
    the `solve_pnp` program gives the answers of XLA's default code generation. (Ours is
    `solve_pnp`'s own stored program of the first rung at bucket 16, which the other
    tests of this file run too: only the default code generation is compiled here.)"""
    from jaxpose.api import _pnp

    assert _programs.compiler_options() == (
        _programs.CPU_COMPILER_OPTIONS if jax.default_backend() == "cpu" else {}
    )
    rng = np.random.default_rng(5)
    scene = jp.apps.random_scene(rng, 12, noise=0.5, world_camera=False)
    K = np.asarray(scene.camera)[:, :3]
    first = _pnp._stages(jp.Options())[0]
    obj, img, mask = _pnp._pad_points(
        np.asarray(scene.model_points), np.asarray(scene.image_points)
    )
    with jax.enable_x64(True):
        packed = np.concatenate([_pnp._values(jp.Options()), _pnp._pack(K, obj, img, mask)])
        stored = _programs.program(_pnp._solve_opencv, first)
        ours = np.asarray(stored(packed))
        lowered = jax.jit(lambda p: _pnp._solve_opencv(p, first)).lower(packed)
        default = np.asarray(
            lowered.compile(compiler_options={"xla_cpu_use_fusion_emitters": True})(packed)
        )
    assert ours[0] == 1
    np.testing.assert_allclose(ours, default, rtol=1e-10, atol=1e-12)


def test_solve_pnp_ransac_runs_a_stored_program():
    """`solve_pnp_ransac` runs a stored program (one per bucket of matches and of
    triplets, loaded by a new process instead of traced and compiled again); its
    threshold and inlier count are the program's values, and another number of matches
    in the same buckets pads to the same shapes: neither compiles anything."""
    rng = np.random.default_rng(11)
    obj, img = _problem(14, seed=11)
    img[:3] += rng.uniform(-60, 60, (3, 2))  # three wrong matches
    ok, _, _, inliers = jp.solve_pnp_ransac(obj, img, K)
    assert ok and len(inliers) == 11

    def ours():
        return [
            p
            for (fn, _), p in _programs._KEYWORD_PROGRAMS.items()
            if fn.__name__ == "_robust_opencv"
        ]

    assert ours(), "no stored program ran"
    compiled = sum(p.compiled for p in ours())
    ok, _, _, inliers = jp.solve_pnp_ransac(obj, img, K, reprojection_error=3.0, min_inliers=5)
    assert ok and len(inliers) == 11
    # 13 matches: 286 triplets, 14: 364, both padded to 16 matches and 384 triplets
    ok, _, _, fewer = jp.solve_pnp_ransac(obj[:13], img[:13], K)
    assert ok and fewer.ravel().tolist() == [i for i in inliers.ravel() if i < 13]
    assert sum(p.compiled for p in ours()) == compiled
