"""Against the real server with its real models (scripts/setup-models.sh):
images sent as raw numpy arrays, as PNG/JPEG files and as arrays encoded
with Pillow; the server's features come back as numpy arrays; a query with
the image of a stored keyframe finds it."""

import shutil
import tempfile
import unittest
from pathlib import Path

import numpy as np

import humem_client as hc
from humem_server import REPO, HumemServer, require

try:
    from PIL import Image as PILImage
except ImportError:  # Pillow is optional for the client; these tests want it
    PILImage = None


def picture(seed: int, height: int = 240, width: int = 320) -> np.ndarray:
    """A made-up RGB scene: smooth colour blobs with edges, one per seed."""
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 256, size=(6, 8, 3)).astype(np.float64)
    # Blocky upscaling, then a light blur: regions with edges between them.
    big = np.kron(coarse, np.ones((height // 6 + 1, width // 8 + 1, 1)))[:height, :width]
    yy, xx = np.mgrid[0:height, 0:width]
    stripes = 40 * np.sin(xx / (5 + seed % 7)) * np.cos(yy / (7 + seed % 5))
    return np.clip(big + stripes[:, :, None], 0, 255).astype(np.uint8)


class ImagesTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        require((REPO / "models" / "efficientnet-lite0").is_dir(), "models/ (run scripts/setup-models.sh)")
        require(PILImage is not None, "Pillow")
        cls.server = HumemServer(perception=True)
        cls.addClassCleanup(cls.server.stop)
        cls.client = hc.connect(cls.server.url, robot_id="cam", session_id="s", timeout=120)
        cls.addClassCleanup(cls.client.close)
        cls.dir = Path(tempfile.mkdtemp(prefix="humem-client-python-images-"))
        cls.addClassCleanup(shutil.rmtree, cls.dir, ignore_errors=True)

    def test_images_from_arrays_and_files_are_stored_and_found(self):
        scenes = [picture(seed) for seed in range(4)]
        # Raw RGB pixels from a numpy array: no encoding, no Pillow.
        raw = self.client.insert(hc.Keyframe(keyframe_id=1, frame_id=100, image=scenes[0]))
        features = raw.features
        self.assertIsInstance(features, hc.Features)
        self.assertEqual(features.global_descriptor.dtype, np.float32)
        self.assertEqual(features.global_descriptor.shape, (1280,))
        self.assertAlmostEqual(float(np.linalg.norm(features.global_descriptor)), 1.0, places=3)
        self.assertIn("descriptor", raw.timings)
        self.assertEqual(features.appearance.shape, (48, 64))
        self.assertEqual(features.appearance.dtype, np.int8)

        # BGR (OpenCV's order) and gray arrays.
        bgr = self.client.insert(hc.Keyframe(keyframe_id=2, frame_id=200,
                                             image=hc.Image.from_array(scenes[1][:, :, ::-1], channels="bgr")))
        rgb = self.client.insert(hc.Keyframe(keyframe_id=99, frame_id=9900, image=scenes[1], session_id="tmp"))
        self.assertGreater(float(bgr.features.global_descriptor @ rgb.features.global_descriptor), 0.999)
        gray = scenes[0].mean(axis=2).astype(np.uint8)
        self.assertEqual(hc.Image.from_array(gray).encoding, hc.ImageEncoding.GRAY8)
        self.client.erase([99], session_id="tmp")

        # A PNG file and a JPEG file, sent as they are.
        png = self.dir / "scene2.png"
        PILImage.fromarray(scenes[2]).save(png)
        jpeg = self.dir / "scene3.jpg"
        PILImage.fromarray(scenes[3]).save(jpeg, quality=92)
        self.client.insert(hc.Keyframe(keyframe_id=3, frame_id=300, image=png))
        self.client.insert(hc.Keyframe(keyframe_id=4, frame_id=400, image=hc.Image.from_file(jpeg)))
        # An array compressed with Pillow before sending.
        encoded = hc.Image.from_array(scenes[2], encode="jpeg")
        self.assertEqual(encoded.encoding, hc.ImageEncoding.JPEG)
        found = self.client.query(image=encoded, frame_id=100_000, threshold=0.0)
        self.assertEqual(found.candidates[0].keyframe_id, 3)

        # The stored keyframe's own image, as a query from another session.
        for i in (0, 1):
            found = self.client.query(image=scenes[i], frame_id=100_000, session_id="other", threshold=0.0)
            self.assertEqual(found.candidates[0].keyframe_id, i + 1, found.keyframe_ids())
            self.assertGreater(found.candidates[0].evidence.descriptor_cosine, 0.99)

    def test_a_file_that_is_not_an_image_is_refused_locally(self):
        path = self.dir / "notes.txt"
        path.write_text("not a picture")
        with self.assertRaisesRegex(ValueError, "neither a JPEG nor a PNG"):
            hc.Image.from_file(path)


if __name__ == "__main__":
    unittest.main()
