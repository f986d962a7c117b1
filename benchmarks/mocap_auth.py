"""Cost of authenticated mocap per sample (issue 20: "measure the cost per sample").

    python -m benchmarks.mocap_auth [--samples 20000] [--repeats 7]

Times what the ground station does with each pose sample it takes, in this process on one core: decoding it
without a key (the baseline: protobuf parse, checks), and decoding it with the key (the MAC checked first), and
the publisher's side (encoding with and without the MAC), and the challenges (with the key only: the ground station
signs one every 10 ms, the publisher checks each). Medians over repeats of the per-sample time, and the
ratio to the baseline run in the same command; at 100-360 Hz mocap the per-period budget is 4 ms (250 Hz loop).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks._util import median, pin_one_core, print_table
from groundstation.control.trajectory import euler_zyx
from groundstation.mocap.auth import MocapKey
from groundstation.mocap.codec import PoseSample, challenge_key, decode, decode_challenge, encode, encode_challenge

KEY_EXPR = "mocap/assembly/pose"


def _per_sample_us(fn, items, repeats: int) -> float:
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for item in items:
            fn(item)
        runs.append((time.perf_counter() - t0) / len(items) * 1e6)
    return median(runs)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args(argv)
    pin_one_core()
    key = MocapKey(bytes(range(32)))
    rng = np.random.default_rng(0)
    poses = [PoseSample(k + 1, 1.7e9 + 0.01 * k, rng.normal(0, 1, 3), euler_zyx(*rng.uniform(-1, 1, 3)),
                        tuple(rng.bytes(16) for _ in range(4)))  # four challenges echoed (ignored without the key)
             for k in range(a.samples)]
    plain = [encode(p) for p in poses]
    signed = [encode(p, key, KEY_EXPR) for p in poses]
    decode_plain = _per_sample_us(lambda s: decode(*s), plain, a.repeats)
    decode_signed = _per_sample_us(lambda s: decode(s[0], s[1], key, KEY_EXPR), signed, a.repeats)
    encode_plain = _per_sample_us(encode, poses, a.repeats)
    encode_signed = _per_sample_us(lambda p: encode(p, key, KEY_EXPR), poses, a.repeats)
    where = challenge_key(KEY_EXPR)
    tokens = [p.echoes[0] for p in poses]
    challenges = [encode_challenge(n, key, where) for n in tokens]
    sign = _per_sample_us(lambda n: encode_challenge(n, key, where), tokens, a.repeats)
    check = _per_sample_us(lambda c: decode_challenge(c[0], c[1], key, where), challenges, a.repeats)
    print_table(f"mocap samples: {a.samples} per run, median of {a.repeats} runs, one core", [
        "side", "without key (us)", "with key (us)", "ratio", "MAC cost (us)"], [
        ["ground station: decode", decode_plain, decode_signed, decode_signed / decode_plain,
         decode_signed - decode_plain],
        ["publisher: encode", encode_plain, encode_signed, encode_signed / encode_plain,
         encode_signed - encode_plain],
        ["ground station: sign a challenge (100/s)", "-", sign, "-", sign],
        ["publisher: check a challenge", "-", check, "-", check]])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
