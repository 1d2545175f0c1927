#!/usr/bin/env python3
"""Seconds per drag frame of a running viewer (`nia-infer view ... --port PORT`).

Requests 12 fast frames (`fast=1`, full size, 10 degrees apart in azimuth) one after another
and prints the median of the last 10 with the last frame's `X-Nia-Stats`. Usage:
    scripts/viewer_drag_time.py PORT
"""
import statistics
import sys
import time
import urllib.request


def main():
    port = sys.argv[1]
    base = f"http://127.0.0.1:{port}"
    for _ in range(120):
        try:
            urllib.request.urlopen(f"{base}/state").read()
            break
        except OSError:
            time.sleep(1)
    else:
        sys.exit(f"no viewer answered on port {port}")
    times, stats = [], None
    for i in range(12):
        start = time.time()
        reply = urllib.request.urlopen(
            f"{base}/render?az={10 * i}&el=0&zoom=1&frame=0&mode=color&scale=1&fast=1"
            f"&client=drag&seq={i}"
        )
        reply.read()
        times.append(time.time() - start)
        stats = reply.headers.get("X-Nia-Stats")
    print(f"drag frame: median {statistics.median(times[2:]):.3f} s over 10 frames "
          f"({', '.join(f'{t:.3f}' for t in times)})")
    print(f"last frame: {stats}")


if __name__ == "__main__":
    main()
