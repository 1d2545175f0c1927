#!/usr/bin/env python3
"""Load on a running `nia-infer view`: 20 clients requesting previews back to back (each its own
client id and increasing request numbers, as the page does while dragging) for SECONDS per
round, three rounds; prints the answers per status, the median latency and the server's
resident memory before and after each round (Linux /proc).

    nia-infer view --model quickstart.nia --subject CoreView_4 --port 8080 &
    python3 scripts/viewer_load.py http://127.0.0.1:8080/ $(pgrep -f "nia-infer view") 20
"""
import sys, threading, time, urllib.request, urllib.error, collections
url, pid, secs = sys.argv[1], sys.argv[2], float(sys.argv[3])
def rss():
    for l in open(f"/proc/{pid}/status"):
        if l.startswith("VmRSS"): return int(l.split()[1])
for round_ in range(3):
    codes = collections.Counter(); lock = threading.Lock(); lat = []
    def client(c):
        seq = 0; end = time.time() + secs
        while time.time() < end:
            seq += 1; t = time.time()
            try:
                r = urllib.request.urlopen(f"{url}render?az={(c*37+seq*7)%360}&el={seq%20}&frame={(c+seq)%6}&scale=0.35&client=c{c}&seq={seq}", timeout=60)
                code = r.status; r.read()
            except urllib.error.HTTPError as e:
                code = e.code
            with lock:
                codes[code] += 1; lat.append(time.time()-t)
    r0 = rss(); t0 = time.time()
    ts = [threading.Thread(target=client, args=(c,)) for c in range(20)]
    [t.start() for t in ts]; [t.join() for t in ts]
    el = time.time() - t0; lat.sort()
    print(f"round {round_}: {sum(codes.values())} requests in {el:.1f} s: {dict(codes)}; median {lat[len(lat)//2]*1e3:.0f} ms; RSS {r0} -> {rss()} kB", flush=True)
