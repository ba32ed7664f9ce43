"""Tests of the Python module mspace (kernel/python, docs/python.md).

Run by CTest with PYTHONPATH set to the built package: python3 -m unittest test_mspace.
Every figure the module returns is checked against an independent computation
here (NumPy) or against what the command line writes for the same run.
"""

import os
import shutil
import signal
import tempfile
import threading
import unittest

import numpy as np

import mspace

SOURCE_DIR = os.environ.get("MSPACE_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))
SIM_POINTS = os.path.join(SOURCE_DIR, "config", "sim_points.yaml")


def ate_rmse(est_t, est_poses, ref_t, ref_poses):
    """ATE after a least-squares SE(2) alignment (closed form), each reference
    pose paired with the estimate interpolated linearly at its time."""
    inside = (ref_t >= est_t[0]) & (ref_t <= est_t[-1])
    ref_xy = ref_poses[inside, :2]
    est_xy = np.column_stack([np.interp(ref_t[inside], est_t, est_poses[:, k]) for k in range(2)])
    est_c, ref_c = est_xy.mean(axis=0), ref_xy.mean(axis=0)
    a, b = est_xy - est_c, ref_xy - ref_c
    theta = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    rot = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    aligned = a @ rot.T + ref_c
    return float(np.sqrt(np.mean(np.sum((aligned - ref_xy) ** 2, axis=1))))


class TempDirTest(unittest.TestCase):
    def setUp(self):
        root = os.environ.get("MSPACE_TEST_TMP")
        if root:
            os.makedirs(root, exist_ok=True)
        self.tmp = tempfile.mkdtemp(dir=root)

    def tearDown(self):
        shutil.rmtree(self.tmp, ignore_errors=True)


class ModuleTest(unittest.TestCase):
    def test_abi_tag_and_plugin_folder(self):
        self.assertTrue(mspace.ABI_TAG.startswith("mspace-sdk"), mspace.ABI_TAG)
        self.assertTrue(os.path.isdir(mspace.PLUGIN_DIR), mspace.PLUGIN_DIR)
        self.assertTrue(any(name.endswith(".so") for name in os.listdir(mspace.PLUGIN_DIR)))


class StepTest(unittest.TestCase):
    def test_stepping_gives_poses_and_a_covariance(self):
        run = mspace.Run(SIM_POINTS, max_steps=150, log_level="off")
        steps = 0
        while run.step():
            steps += 1
            if steps == 50:
                pose = run.pose
                self.assertEqual(pose.shape, (6,))
                cov = run.robot_covariance
                self.assertEqual(cov.shape[0], cov.shape[1])
                np.testing.assert_allclose(cov, cov.T, atol=1e-12)
                self.assertGreater(np.linalg.eigvalsh(cov).min(), 0.0)
        self.assertEqual(steps, 150)
        self.assertEqual(run.steps_done, 150)
        t, poses = run.trajectory()
        self.assertEqual(poses.shape[1], 6)
        self.assertEqual(len(t), len(poses))
        self.assertTrue(np.all(np.diff(t) > 0))
        np.testing.assert_allclose(poses[-1], run.pose, atol=1e-12)


class RunTest(TempDirTest):
    def test_run_matches_an_independent_ate_and_the_features(self):
        run = mspace.Run(SIM_POINTS, out=self.tmp, log_level="off")
        summary = run.run(progress=False)
        self.assertEqual(summary["steps"], run.steps_done)
        self.assertIsNone(summary["interrupted"])
        self.assertGreater(summary["source_load_seconds"], 0.0)  # timed on its own, before the first step
        est_t, est = run.evaluated_trajectory()
        ref_t, ref = run.ground_truth()
        self.assertGreater(len(ref_t), 100)
        # The summary's ATE, recomputed here from the arrays the module returns.
        self.assertAlmostEqual(summary["errors"]["ate_rmse"], ate_rmse(est_t, est, ref_t, ref), places=6)
        self.assertLess(summary["errors"]["ate_rmse"], 0.2)  # README: 0.059 m under ekf
        features = run.features()
        counted = sum(sum(by_dim.values()) for by_dim in summary["features_by_dim"].values())
        self.assertEqual(len(features), counted)
        for f in features:
            self.assertTrue(np.all(np.isfinite(f.coords)))
            if f.covariance is not None:
                self.assertEqual(f.covariance.shape, (f.mspace_dim, f.mspace_dim))
                np.testing.assert_allclose(f.covariance, f.covariance.T, atol=1e-12)
        self.assertIn("trajectory.tum", run.output_files)
        self.assertTrue(os.path.isfile(os.path.join(self.tmp, "summary.yaml")))

    def test_overrides_change_the_run_like_set(self):
        a = mspace.Run(SIM_POINTS, max_steps=100, log_level="off")
        b = mspace.Run(SIM_POINTS, max_steps=100, log_level="off", set={"run.seed": 7})
        c = mspace.Run(SIM_POINTS, max_steps=100, log_level="off", set=["run.seed=7"])
        for run in (a, b, c):
            while run.step():
                pass
        self.assertGreater(np.abs(a.trajectory()[1] - b.trajectory()[1]).max(), 1e-6)
        np.testing.assert_array_equal(b.trajectory()[1], c.trajectory()[1])

    def test_estimator_is_one_argument(self):
        run = mspace.Run(SIM_POINTS, max_steps=20, log_level="off", estimator="cekf")
        self.assertEqual(run.estimator, "cekf")
        self.assertIn("plugin: cekf", run.config_yaml)

    def test_saved_map_reads_back_exactly(self):
        run = mspace.Run(SIM_POINTS, out=self.tmp, max_steps=400, log_level="off")
        run.run(progress=False)
        saved = mspace.load_map(self.tmp)
        features = {f.id: f for f in run.features()}
        self.assertEqual(len(saved), len(features))
        for f in saved.features:
            live = features[f.id]
            self.assertEqual((f.type, f.plugin, f.mspace_dim), (live.type, live.plugin, live.mspace_dim))
            np.testing.assert_allclose(f.coords, live.coords, rtol=0, atol=1e-12)
            if live.covariance is not None:
                np.testing.assert_allclose(f.covariance, live.covariance, rtol=0, atol=1e-12)


class ErrorTest(TempDirTest):
    def test_unknown_key_names_the_key(self):
        with self.assertRaises(mspace.ConfigError) as caught:
            mspace.Run(SIM_POINTS, set={"features.point.no_such_parameter": 1}, log_level="off")
        self.assertIn("no_such_parameter", str(caught.exception))
        self.assertIsInstance(caught.exception, ValueError)

    def test_missing_file_says_so(self):
        with self.assertRaises(mspace.ConfigError) as caught:
            mspace.Run(os.path.join(self.tmp, "absent.yaml"), log_level="off")
        self.assertIn("no such file", str(caught.exception))

    def test_unknown_estimator_names_the_plugin(self):
        with self.assertRaises(Exception) as caught:
            mspace.Run(SIM_POINTS, estimator="no_such_estimator", log_level="off")
        self.assertIn("no_such_estimator", str(caught.exception))

    def test_corrupt_map_names_the_file(self):
        bad = os.path.join(self.tmp, "map.bin")
        with open(bad, "wb") as out:
            out.write(b"not a map at all" * 8)
        with self.assertRaises(mspace.MapFileError) as caught:
            mspace.load_map(bad)
        self.assertIn("map.bin", str(caught.exception))


class InterruptTest(TempDirTest):
    def test_ctrl_c_writes_the_outputs_and_raises(self):
        # Ten laps of the simulated world: long enough for the timer on a slow machine.
        run = mspace.Run(SIM_POINTS, out=self.tmp, set={"source.laps": 20}, log_level="off")
        for _ in range(5):
            run.step()
        timer = threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT))
        timer.start()
        try:
            with self.assertRaises(KeyboardInterrupt):
                run.run(progress=False)
        finally:
            timer.cancel()
        self.assertGreater(run.steps_done, 5)
        with open(os.path.join(self.tmp, "summary.yaml")) as summary:
            self.assertIn("KeyboardInterrupt", summary.read())
        self.assertTrue(os.path.isfile(os.path.join(self.tmp, "trajectory.tum")))


if __name__ == "__main__":
    unittest.main()
