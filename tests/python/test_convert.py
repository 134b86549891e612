#!/usr/bin/env python3
"""Unit tests of the Python client's encoding: poses (matrix <-> quaternion), packed points,
regions, answer merging and per-call metadata. No server needed; the generated stubs are (they
define the messages), so it runs with a Python that has rim_client installed (the build's venv)."""

from __future__ import annotations

import math
import unittest

import numpy as np

import rim_client
from rim.v1 import rim_pb2
from rim_client import convert
from rim_client.errors import code_name
from rim_client.session import _merge


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return q if np.linalg.det(q) > 0 else -q


def axis_angle(axis, angle: float) -> np.ndarray:
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * skew + (1 - math.cos(angle)) * skew @ skew


class PoseTest(unittest.TestCase):

    def test_quaternion_round_trip_covers_every_branch(self) -> None:
        rng = np.random.default_rng(0)
        rotations = [random_rotation(rng) for _ in range(200)]
        # Near 180 degrees about each axis the trace is about -1: the other three branches.
        rotations += [axis_angle(axis, math.pi - 1e-3) for axis in np.eye(3)]
        rotations += [axis_angle((1, 2, 3), math.pi), np.eye(3)]
        for rotation in rotations:
            q = convert.rotation_to_quaternion(rotation)
            self.assertAlmostEqual(float(np.linalg.norm(q)), 1.0, places=12)
            self.assertGreaterEqual(q[0], 0.0)
            np.testing.assert_allclose(convert.quaternion_to_rotation(q), rotation, atol=1e-12)

    def test_known_yaw(self) -> None:
        q = convert.rotation_to_quaternion(axis_angle((0, 0, 1), math.pi / 2))
        np.testing.assert_allclose(q, (math.sqrt(0.5), 0, 0, math.sqrt(0.5)), atol=1e-12)

    def test_matrix_and_pair_give_the_same_message(self) -> None:
        pose = np.eye(4)
        pose[:3, :3] = axis_angle((0.3, -1, 0.2), 2.5)
        pose[:3, 3] = (1.5, -2.0, 0.25)
        from_matrix = convert.pose_to_proto(pose)
        pair = (pose[:3, 3], convert.rotation_to_quaternion(pose[:3, :3]))
        self.assertEqual(from_matrix, convert.pose_to_proto(pair))
        self.assertEqual((from_matrix.translation.x, from_matrix.translation.y,
                          from_matrix.translation.z), (1.5, -2.0, 0.25))

    def test_bad_poses_name_the_problem(self) -> None:
        scaled = np.eye(4)
        scaled[:3, :3] *= 1.1
        mirrored = np.diag([1.0, 1.0, -1.0, 1.0])
        projective = np.eye(4)
        projective[3, 0] = 0.5
        cases = [(scaled, "not a rotation"), (mirrored, "not a rotation"),
                 (projective, "last row"), (np.eye(3), "shape (3, 3)"),
                 (([0, 0], [1, 0, 0, 0]), "sizes (2, 4)"), ("abc", "numeric")]
        for pose, words in cases:
            with self.assertRaises(rim_client.RimError) as error:
                convert.pose_to_proto(pose, "frame 7: pose")
            self.assertEqual(error.exception.code, "INVALID_ARGUMENT")
            self.assertIn("frame 7: pose", error.exception.message)
            self.assertIn(words, error.exception.message)

    def test_values_the_server_checks_are_sent_as_given(self) -> None:
        # A non-unit quaternion and NaNs reach the server, which rejects them naming the field.
        message = convert.pose_to_proto(((0, 0, 0), (2, 0, 0, 0)))
        self.assertEqual(message.rotation.w, 2.0)
        nan_pose = np.eye(4)
        nan_pose[0, 3] = np.nan
        self.assertTrue(math.isnan(convert.pose_to_proto(nan_pose).translation.x))


class PointsTest(unittest.TestCase):

    def test_packs_little_endian_float32_triples(self) -> None:
        points = np.array([[1, 2, 3], [4.5, -5, 6]], dtype=">f8")  # big-endian doubles in
        packed = convert.pack_points(points, "points")
        self.assertEqual(len(packed), 24)
        np.testing.assert_array_equal(np.frombuffer(packed, "<f4").reshape(2, 3), points)
        self.assertEqual(convert.pack_points([[0, 0, 1]], "points"),
                         np.array([0, 0, 1], "<f4").tobytes())

    def test_shapes_are_checked(self) -> None:
        for bad, words in [(np.zeros(3), "shape (3,)"), (np.zeros((2, 4)), "shape (2, 4)"),
                           ([["a", "b", "c"]], "numeric")]:
            with self.assertRaises(rim_client.RimError) as error:
                convert.as_points(bad, "frame 2: points")
            self.assertEqual(error.exception.code, "INVALID_ARGUMENT")
            self.assertIn("frame 2: points", error.exception.message)
            self.assertIn(words, error.exception.message)

    def test_region(self) -> None:
        box = convert.box_to_proto(((0, 1, 2), (3, 4, 5)))
        self.assertEqual((box.min.y, box.max.z), (1.0, 5.0))
        for bad in [((1, 0, 0), (0, 1, 1)), ((0, 0), (1, 1)), ((0, 0, np.inf), (1, 1, 1))]:
            with self.assertRaises(rim_client.RimError):
                convert.box_to_proto(bad)


class AnswerTest(unittest.TestCase):

    def response(self, sdf, observed, gradient=None, version=3):
        return rim_pb2.QuerySdfResponse(
            sdf=np.asarray(sdf, "<f4").tobytes(), observed=bytes(observed),
            gradient=b"" if gradient is None else np.asarray(gradient, "<f4").tobytes(),
            map_version=version, server_seconds=0.5)

    def test_chunks_are_concatenated_in_order(self) -> None:
        result = _merge([self.response([1, 2], [1, 0], [[0, 0, 1], [0, 1, 0]], 3),
                         self.response([3], [1], [[1, 0, 0]], 3)], 3, gradient=True)
        np.testing.assert_array_equal(result.sdf, [1, 2, 3])
        np.testing.assert_array_equal(result.observed, [True, False, True])
        np.testing.assert_array_equal(result.gradient, [[0, 0, 1], [0, 1, 0], [1, 0, 0]])
        self.assertEqual((result.map_version, result.server_seconds), (3, 1.0))

    def test_a_short_answer_is_data_loss(self) -> None:
        with self.assertRaises(rim_client.RimError) as error:
            _merge([self.response([1, 2], [1, 1])], 3, gradient=False)
        self.assertEqual(error.exception.code, "DATA_LOSS")
        self.assertIn("for 3 points", error.exception.message)


class MetadataTest(unittest.TestCase):

    def test_robot_and_token_headers(self) -> None:
        # The channel connects lazily: no server is contacted here.
        with rim_client.Client("127.0.0.1:1", token="s3cret") as client:
            self.assertEqual(client._metadata("robot_1"),
                             [("x-robot-id", "robot_1"), ("authorization", "Bearer s3cret")])
            self.assertEqual(client._metadata(), [("authorization", "Bearer s3cret")])
        with rim_client.Client("127.0.0.1:1") as client:
            self.assertEqual(client._metadata("r"), [("x-robot-id", "r")])

    def test_status_code_names(self) -> None:
        self.assertEqual(code_name(5), "NOT_FOUND")
        self.assertEqual(code_name(3), "INVALID_ARGUMENT")
        self.assertEqual(code_name(999), "UNKNOWN")

    def test_robot_id_must_be_a_string(self) -> None:
        with rim_client.Client("127.0.0.1:1") as client:
            with self.assertRaises(rim_client.RimError) as error:
                client.session(None)
            self.assertIn("robot_id", error.exception.message)


if __name__ == "__main__":
    unittest.main(verbosity=2)
