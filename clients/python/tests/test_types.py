"""The typed layer without a server: the enums and dataclasses mirror the
proto (a field or value added to humem.proto without its Python
counterpart fails here), poses convert to and from matrices, images are
made from arrays and files, features are checked, and options that do not
fit together are refused."""

import tempfile
import unittest
from pathlib import Path

import numpy as np

import humem_client as hc
from humem_client import _convert
from humem_client.proto import humem_pb2 as pb
from humem_server import require


def proto_fields(message) -> set:
    return {f.name for f in message.DESCRIPTOR.fields}


def dataclass_fields(cls) -> set:
    return set(cls.__dataclass_fields__)


class MirrorTest(unittest.TestCase):
    def test_every_proto_enum_value_has_its_member(self):
        pairs = [
            (hc.Scope, pb.Scope, "SCOPE_"),
            (hc.Layers, pb.Layers, "LAYERS_"),
            (hc.QueryKind, pb.QueryKind, "QUERY_KIND_"),
            (hc.QueryStatus, pb.QueryStatus, "QUERY_STATUS_"),
            (hc.VerificationKind, pb.VerificationKind, "VERIFICATION_KIND_"),
            (hc.VerificationOutcome, pb.VerificationOutcome, "VERIFICATION_OUTCOME_"),
            (hc.ImageEncoding, pb.Image.Encoding, "ENCODING_"),
        ]
        for ours, theirs, prefix in pairs:
            expected = {name[len(prefix):]: number for name, number in theirs.items()}
            self.assertEqual({m.name: m.value for m in ours}, expected, ours.__name__)
        self.assertEqual({e.name for e in pb.DESCRIPTOR.enum_types_by_name.values()},
                         {"Scope", "Layers", "QueryKind", "QueryStatus", "VerificationKind", "VerificationOutcome"})

    def test_answers_carry_every_field_of_their_message(self):
        pairs = [
            (hc.InsertResult, pb.InsertResponse),
            (hc.InsertBatchResult, pb.InsertBatchResponse),
            (hc.EraseResult, pb.EraseResponse),
            (hc.EraseResult, pb.ResetMapResponse),
            (hc.EraseResult, pb.ResetSessionResponse),
            (hc.UpdatePosesResult, pb.UpdatePosesResponse),
            (hc.VerificationResult, pb.ReportVerificationResponse),
            (hc.QueryResult, pb.QueryResponse),
            (hc.Candidate, pb.Candidate),
            (hc.Evidence, pb.Evidence),
            (hc.ObjectMatch, pb.ObjectMatch),
            (hc.TextMatch, pb.TextMatch),
            (hc.TextConflict, pb.TextConflict),
            (hc.MissingObject, pb.MissingObject),
            (hc.DriftEnvelope, pb.DriftEnvelope),
            (hc.Stats, pb.StatsResponse),
            (hc.MapStats, pb.MapStats),
            (hc.OperatingPoint, pb.OperatingPoint),
            (hc.Features, pb.Features),
            (hc.ObjectObservation, pb.ObjectObservation),
            (hc.TextObservation, pb.TextObservation),
            (hc.MapRef, pb.MapRef),
            (hc.PoseUpdate, pb.PoseUpdate),
            (hc.KeyframeRef, pb.KeyframeRef),
            (hc.Image, pb.Image),
        ]
        for ours, theirs in pairs:
            self.assertEqual(dataclass_fields(ours), proto_fields(theirs), f"{ours.__name__} vs {theirs.__name__}")
        # Requests: the oneof `content` is the features/image pair.
        self.assertEqual(dataclass_fields(hc.Keyframe), proto_fields(pb.Keyframe))
        self.assertEqual(dataclass_fields(hc.Query), proto_fields(pb.QueryRequest))
        self.assertEqual(set(pb.DESCRIPTOR.services_by_name["PlaceRecognition"].methods_by_name),
                         {"Insert", "InsertBatch", "Query", "Erase", "ResetMap", "ResetSession", "UpdatePoses",
                          "Stats", "ReportVerification"})

    def test_the_drift_envelope_is_carried_when_set(self):
        message = pb.Candidate()
        self.assertIsNone(_convert.candidate_from_proto(message).evidence.drift)
        message.evidence.drift.distance = 3.0
        message.evidence.drift.path = 213.0
        message.evidence.drift.ratio = 3.0 / 213.0
        message.evidence.drift.allowance = 25.8
        message.evidence.drift.penalty = 0.0
        drift = _convert.candidate_from_proto(message).evidence.drift
        self.assertEqual(drift, hc.DriftEnvelope(distance=3.0, path=213.0, ratio=3.0 / 213.0, allowance=25.8, penalty=0.0))

    def test_a_full_query_request_round_trips(self):
        q = hc.Query(frame_id=7, keyframe_id=3, map_id=2, features=hc.Features(
            global_descriptor=[1, 2, 3], scene={5: 0.5},
            objects=[hc.ObjectObservation("sign", 0.9, 0.5, 0.4, 0.02, texts=[("B-214", 0.8)])],
            appearance=np.arange(3072) % 100), predecessor_keyframe_ids=[2, 1], scope=hc.Scope.LISTED,
            robot_ids=["car-2"], maps=[hc.MapRef("car-3", 4)], min_frame_gap=0, top_n=3, threshold=0.5,
            layers=hc.Layers.SCAL_OSRL, kind=hc.QueryKind.RELOCALISATION, min_log_sequence=0, exact=True)
        m = _convert.query_to_proto(q, "me", "s")
        self.assertTrue(m.exact)
        self.assertEqual((m.robot_id, m.session_id, m.frame_id, m.keyframe_id, m.map_id), ("me", "s", 7, 3, 2))
        for name in ("min_frame_gap", "min_log_sequence", "top_n", "threshold"):
            self.assertTrue(m.HasField(name), name)  # 0 is sent, not left to the default
        self.assertFalse(m.maps[0].HasField("session_id"))
        self.assertEqual((m.scope, m.layers, m.kind), (pb.SCOPE_LISTED, pb.LAYERS_SCAL_OSRL,
                                                      pb.QUERY_KIND_RELOCALISATION))
        back = _convert.features_from_proto(m.features)
        np.testing.assert_array_equal(back.global_descriptor, [1, 2, 3])
        np.testing.assert_array_equal(back.appearance.reshape(-1), np.arange(3072) % 100)
        self.assertEqual(back.objects[0].texts[0].text, "B-214")
        self.assertEqual(_convert.query_to_proto(hc.Query(), "me", "s").HasField("threshold"), False)


class PoseTest(unittest.TestCase):
    def test_matrix_round_trip(self):
        rng = np.random.default_rng(1)
        for _ in range(50):
            q = rng.standard_normal(4)
            pose = hc.Pose(translation=rng.standard_normal(3), rotation=q / np.linalg.norm(q))
            m = pose.matrix()
            np.testing.assert_allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-12)
            again = hc.Pose.from_matrix(m)
            np.testing.assert_allclose(again.matrix(), m, atol=1e-12)
            np.testing.assert_allclose(abs(again.rotation @ pose.rotation), 1.0, atol=1e-12)
        # A half turn about z: the branch where w is not the largest.
        half = hc.Pose.from_matrix(np.diag([-1.0, -1.0, 1.0, 1.0]))
        np.testing.assert_allclose(np.abs(half.rotation), [0, 0, 0, 1], atol=1e-12)
        with self.assertRaises(ValueError):
            hc.Pose(translation=[1, 2])


class ImageTest(unittest.TestCase):
    def test_arrays(self):
        rgb = np.random.default_rng(0).integers(0, 256, (20, 30, 3), dtype=np.uint8)
        image = hc.Image.from_array(rgb)
        self.assertEqual((image.encoding, image.width, image.height, len(image.data)),
                         (hc.ImageEncoding.RGB8, 30, 20, 1800))
        self.assertEqual(hc.Image.from_array(rgb, channels="bgr").encoding, hc.ImageEncoding.BGR8)
        # A non-contiguous view is packed.
        self.assertEqual(hc.Image.from_array(rgb[:, ::2]).data, np.ascontiguousarray(rgb[:, ::2]).tobytes())
        gray = hc.Image.from_array(rgb[:, :, :1])
        self.assertEqual((gray.encoding, len(gray.data)), (hc.ImageEncoding.GRAY8, 600))
        with self.assertRaisesRegex(ValueError, "uint8"):
            hc.Image.from_array(rgb.astype(np.float32))
        with self.assertRaisesRegex(ValueError, "RGBA only with encode='png'"):
            hc.Image.from_array(np.zeros((20, 30, 4), np.uint8))

    def test_files_and_encoding(self):
        try:
            from PIL import Image as PILImage
        except ImportError:
            PILImage = None
        require(PILImage is not None, "Pillow")
        rgb = np.random.default_rng(0).integers(0, 256, (20, 30, 3), dtype=np.uint8)
        png = hc.Image.from_array(rgb, encode="png")
        self.assertEqual(png.encoding, hc.ImageEncoding.PNG)
        import io

        np.testing.assert_array_equal(np.asarray(PILImage.open(io.BytesIO(png.data))), rgb)
        bgr_png = hc.Image.from_array(rgb[:, :, ::-1], channels="bgr", encode="png")
        self.assertEqual(bgr_png.data, png.data)
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "a.jpg"
            PILImage.fromarray(rgb).save(path)
            image = hc.Image.from_file(path)
            self.assertEqual(image.encoding, hc.ImageEncoding.JPEG)
            self.assertEqual(hc.Image.from_file(str(path)).data, path.read_bytes())
        self.assertEqual(hc.Image.from_bytes(png.data).encoding, hc.ImageEncoding.PNG)
        with self.assertRaisesRegex(ValueError, "neither JPEG nor PNG"):
            hc.Image.from_bytes(b"GIF89a")


class FeaturesTest(unittest.TestCase):
    def test_checks_and_helpers(self):
        f = hc.Features(global_descriptor=[1, 2], scene=[(3, 0.25)])
        self.assertEqual(f.global_descriptor.dtype, np.float32)
        self.assertEqual(f.scene, {3: 0.25})
        with self.assertRaisesRegex(ValueError, "1-D"):
            hc.Features(global_descriptor=np.ones((2, 2)))
        with self.assertRaisesRegex(ValueError, "3072"):
            hc.Features(global_descriptor=[1], appearance=np.ones(10))
        probs = np.array([0.1, 0.5, 0.05, 0.35])
        self.assertEqual(hc.Features.top_scene(probs, k=2), {1: 0.5, 3: 0.35})


class OptionsTest(unittest.TestCase):
    def test_options_that_do_not_fit_are_refused(self):
        with self.assertRaisesRegex(ValueError, "token: only sent over TLS"):
            hc.connect("127.0.0.1:1", token="hm1.x")
        with self.assertRaisesRegex(ValueError, "tls_server_name: set, but target"):
            hc.connect("http://127.0.0.1:1", tls_server_name="humem")
        with self.assertRaisesRegex(ValueError, "give both or neither"):
            hc.connect("https://127.0.0.1:1", tls_key="k.pem")


if __name__ == "__main__":
    unittest.main()
