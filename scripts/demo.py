#!/usr/bin/env python3
"""The main job (until the simulator lands): kidnap a robot to a random free pose on the
shipped office map, ray-cast one 270 deg / 20 m scan there, localize it with the CLI, and
print the estimated and the true pose with the error, and where the picture is."""
import json
import math
import os
import random
import subprocess
import sys

root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
out_dir = os.path.join(root, 'out')
os.makedirs(out_dir, exist_ok=True)
seed = int(sys.argv[1]) if len(sys.argv) > 1 else random.randrange(1_000_000)
method = sys.argv[2] if len(sys.argv) > 2 else 'template_ccoeff'
plot = os.path.join(out_dir, 'demo.png')

scan = subprocess.run([sys.executable, '-m', 'global_loc', 'simulate', '--count', '1', '--seed', str(seed)],
                      check=True, capture_output=True, text=True).stdout
print(f'kidnapped the robot to a random free pose (seed {seed}); localizing one 270 deg scan with {method} ...')
res = subprocess.run([sys.executable, '-m', 'global_loc', 'localize', '--scans', '-', '--method', method,
                      '--plot', plot], input=scan, check=True, capture_output=True, text=True).stdout
row = json.loads(res)
t = row['truth']
print(f'  true pose:      x={t["x"]:7.3f}  y={t["y"]:7.3f}  yaw={math.degrees(t["yaw"]):7.1f} deg')
if 'x' in row:
    print(f'  estimated pose: x={row["x"]:7.3f}  y={row["y"]:7.3f}  yaw={math.degrees(row["yaw"]):7.1f} deg')
    print(f'  error: {row["error_xy"]:.3f} m, {row["error_yaw_deg"]:.1f} deg;  score {row["score"]}, '
          f'{row["message"]}, {row["time_s"]:.2f} s')
else:
    print(f'  no pose: {row.get("message") or row.get("error")}')
print(f'  picture: {plot}')
