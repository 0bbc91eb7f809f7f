"""Against the real server over real TLS with tokens: certificates made at
test time with openssl (scripts/make-dev-certs.sh), tokens with
``humem token add``. A client trusting the CA with its robot's token
inserts, queries and erases; no token is UNAUTHENTICATED, another robot's
ids PERMISSION_DENIED, another CA or plaintext UNAVAILABLE."""

import shutil
import tempfile
import unittest
from pathlib import Path

import grpc

import humem_client as hc
from humem_server import HumemServer, add_token, make_tls_dir, near, random_descriptor, require


class TlsWithTokensTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        require(shutil.which("openssl") is not None, "the openssl command (it makes the test certificates)")
        cls.dir = Path(tempfile.mkdtemp(prefix="humem-client-python-tls-"))
        cls.addClassCleanup(shutil.rmtree, cls.dir, ignore_errors=True)
        make_tls_dir(cls.dir)
        tokens = cls.dir / "tokens.json"
        cls.token = add_token(tokens, "car-1")
        cls.server = HumemServer(env={
            "HUMEM_SERVER__TLS__CERT": str(cls.dir / "tls.crt"),
            "HUMEM_SERVER__TLS__KEY": str(cls.dir / "tls.key"),
            "HUMEM_AUTH__TOKENS_FILE": str(tokens),
        })
        cls.addClassCleanup(cls.server.stop)

    def connect(self, **options) -> hc.Client:
        settings = dict(robot_id="car-1", session_id="s", tls_ca=self.dir / "ca.crt", token=self.token, timeout=10)
        settings.update(options)
        return hc.connect(settings.pop("target", self.server.https), **settings)

    def test_insert_query_and_erase_over_tls_with_a_token(self):
        self.assertTrue(self.token.startswith("hm1."), self.token)
        with self.connect() as client:
            client.wait_ready(10)
            for i in range(1, 4):
                client.insert(hc.Keyframe(keyframe_id=i, frame_id=100 * i, features=random_descriptor(i)))
            result = client.query(features=near(random_descriptor(2), 2), frame_id=10_000, threshold=0.0)
            self.assertEqual(result.candidates[0].keyframe_id, 2)
            self.assertEqual(client.erase([1, 2, 3]).erased, 3)
        # By name too, with the certificate checked for it.
        name = self.server.https.replace("127.0.0.1", "localhost")
        with self.connect(target=name) as client:
            self.assertEqual(client.stats().keyframes, 0)
        # Connecting by address while checking the certificate for its name.
        with self.connect(tls_server_name="localhost") as client:
            self.assertEqual(client.stats().keyframes, 0)

    def test_without_a_token_the_call_is_unauthenticated(self):
        with self.connect(token=None) as client:
            with self.assertRaises(hc.UnauthenticatedError) as caught:
                client.insert(hc.Keyframe(keyframe_id=1, frame_id=1, features=random_descriptor(1)))
            self.assertEqual(caught.exception.code, grpc.StatusCode.UNAUTHENTICATED)
        with self.connect(token="hm1.00000000.forged") as client:
            with self.assertRaises(hc.UnauthenticatedError):
                client.stats()

    def test_a_robot_token_may_not_write_for_another_robot(self):
        with self.connect(robot_id="car-2") as client:
            with self.assertRaises(hc.PermissionDeniedError) as caught:
                client.insert(hc.Keyframe(keyframe_id=1, frame_id=1, features=random_descriptor(1)))
            self.assertEqual(caught.exception.code, grpc.StatusCode.PERMISSION_DENIED)

    def test_another_ca_or_plaintext_fails_cleanly(self):
        with self.connect(tls_ca=self.dir / "other" / "ca.crt") as client:
            with self.assertRaises(hc.UnavailableError):
                client.stats()
        with hc.connect(self.server.url, robot_id="car-1", timeout=10) as client:
            with self.assertRaises(hc.UnavailableError):
                client.stats()
        # The server goes on serving.
        with self.connect() as client:
            client.stats()

    def test_tls_options_need_an_https_target(self):
        with self.assertRaisesRegex(ValueError, "token: only sent over TLS"):
            hc.connect(self.server.url, token=self.token)
        with self.assertRaisesRegex(ValueError, "not an https:// URL"):
            hc.connect(self.server.url, tls_ca=self.dir / "ca.crt")
        with self.assertRaisesRegex(ValueError, "give both or neither"):
            hc.connect(self.server.https, tls_cert=self.dir / "tls.crt")
        with self.assertRaisesRegex(ValueError, "tls_ca: cannot read"):
            hc.connect(self.server.https, tls_ca=self.dir / "missing.crt")


if __name__ == "__main__":
    unittest.main()
