#!/usr/bin/env python3
"""Quick start for humem_client: stores a short drive of keyframes with
descriptors, revisits a place and asks HuMem which keyframe shows it, asks
again latest-wins style, culls a keyframe and prints the store's stats.

    python examples/quickstart.py [TARGET] [--ca CA.crt --token TOKEN]

TARGET defaults to $HUMEM_TARGET or 127.0.0.1:50051 (``humem serve``'s
default); use https://host:port with --ca and --token (or $HUMEM_TOKEN)
for a fleet server. Use a scratch server: every keyframe of one store has
descriptors of one length (here 256 values), and a store that already
holds another length refuses these. The client's tests run this script
against a real server.
"""

import argparse
import os
import sys

import numpy as np

import humem_client as hc


def main() -> int:
    parser = argparse.ArgumentParser(description="humem_client quick start")
    parser.add_argument("target", nargs="?", default=os.environ.get("HUMEM_TARGET", "127.0.0.1:50051"))
    parser.add_argument("--ca", help="CA certificate the server's TLS certificate chains to")
    parser.add_argument("--token", default=os.environ.get("HUMEM_TOKEN"), help="bearer token (humem token add)")
    parser.add_argument("--robot", default="quickstart-robot")
    args = parser.parse_args()

    with hc.connect(args.target, robot_id=args.robot, session_id="demo", tls_ca=args.ca, token=args.token) as client:
        client.reset_session()  # start clean: this demo's keyframes only

        # 1. A drive along 20 places, one keyframe each (ids, frames, poses,
        #    and a descriptor per place: here random, in a SLAM system the
        #    output of its place model; or send `image=` a numpy array or
        #    a JPEG/PNG file and the server's models make the features).
        rng = np.random.default_rng(7)
        places = rng.standard_normal((20, 256)).astype(np.float32)
        for i, descriptor in enumerate(places):
            pose = hc.Pose(translation=[2.0 * i, 0.0, 0.0])  # T_wc: the camera 2 m further each time
            client.insert(hc.Keyframe(keyframe_id=i, frame_id=10 * i, map_id=0, pose=pose, features=descriptor))

        # 2. Back at place 5, much later: a loop-closure query in the same map.
        revisit = places[5] + 0.1 * rng.standard_normal(256).astype(np.float32)
        result = client.query(features=revisit, frame_id=5000, map_id=0, scope=hc.Scope.SAME_MAP)
        for c in result.candidates:
            x, y, z = c.pose.translation
            print(f"candidate keyframe {c.keyframe_id}: score {c.score:.3f} "
                  f"(descriptor cosine {c.evidence.descriptor_cosine:.3f}) at ({x:.1f}, {y:.1f}, {z:.1f})")
        if not result.candidates:
            print(f"no candidate above the threshold {result.threshold:.2f}")
            return 1

        # 3. The same, latest wins: submit and carry on; a newer query of the
        #    kind replaces one still waiting. Wait for this one's outcome.
        ticket = client.submit_query(features=revisit, frame_id=5001, map_id=0, scope=hc.Scope.SAME_MAP)
        outcome = ticket.outcome(timeout=30)
        print(f"latest-wins ticket {ticket.id}: {outcome.state.value}, "
              f"best keyframe {outcome.candidates[0].keyframe_id if outcome.candidates else None}")

        # 4. A bad request: the error names the field.
        try:
            client.insert(hc.Keyframe(keyframe_id=50, frame_id=500, features=np.zeros(256)))
        except hc.InvalidArgumentError as e:
            print(f"refused as expected: {e.code.name}: {e.message}")

        # 5. ORB-SLAM3 culls a keyframe; then what the store holds.
        print(f"erased {client.erase([3]).erased} keyframe")
        stats = client.stats()
        print(f"store: {stats.keyframes} keyframes of {stats.descriptor_dim} values, server {stats.server_version}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
