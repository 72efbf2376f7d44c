#!/bin/bash
# Rebuild rbench against mcrad-raycast (picks up any change in its sources) and run the
# mcrad / Embree / obvhs comparison on the three scenes, then print a compact table.
#
#   crates/raycast/benches/embree/run.sh          # mcrad-raycast from this checkout
#   MCRAD_RAYCAST=/path/to/crates/raycast ./run.sh   # another checkout (e.g. the HEAD snapshot)
#   OUT=raw.txt ./run.sh                          # where the raw output goes (default results-<time>.txt)
#   CORNELL="5 10000000" ROOM100K="3 3000000" ROOM1M="3 2000000" ./run.sh   # "rounds rays" per scene
#   TABLE_ONLY=file ./run.sh                      # just print the table of an earlier raw output
#   MAIN_REV=main ./run.sh                         # occlusion and closest hits of this checkout
#       against a copy of the repository at MAIN_REV and Embree, alternating in one process
#       (rbench's `occl` command; OCCL_ROOMS / OCCL_CORNELL: "rounds pairs chunk")
#
# Never writes to the checkout: the build goes to $B/target (B: a scratch directory, required).
# The first run sets up $B: Debian's Embree 3 (libembree-dev), a copy of the stand-alone benchmark
# (RBENCH: its source directory, required then) with mcrad-modes.patch applied, and the scenes
# and rays (~2 GB).
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
B=${B:?set B to a scratch directory outside the checkout}
if [ ! -d "$B/src" ]; then
  dpkg -s libembree-dev >/dev/null 2>&1 || { apt-get update && apt-get install -y libembree-dev; }
  mkdir -p "$B" && cp -r "${RBENCH:?set RBENCH to the source directory of the stand-alone benchmark}" "$B/src" && chmod -R u+w "$B/src"
  patch -p1 -d "$B/src" < "$HERE/mcrad-modes.patch"
fi
table() {
python3 - "$1" <<'EOF'
import sys, re
rows, builds, agree = {}, {}, {}
for line in open(sys.argv[1]):
    w = line.split()
    if not w: continue
    if w[0] == 'TABLE':
        scene, query, th = w[1], w[2], w[3].split('=')[1]
        kv = dict(zip(w[4::2], w[5::2]))
        rows.setdefault((scene, query), {})[th] = kv
    elif w[0] == 'TABLEBUILD':
        builds[w[1]] = dict(zip(w[2::2], w[3::2]))
    elif w[0] == 'MCAGREE' and w[2] in ('closest:', 'closest-same-line:'):
        m = re.search(r'= ([0-9.]+)%', line)
        agree[(w[1], w[2])] = (m.group(1) if m else '?') + '%'
q_short = {'closest': 'closest', 'occluded': 'occluded', 'closest-sorted-by-source': 'closest-sorted', 'occluded-facing': 'occl-facing'}
hdr = ['scene', 'query']
for th in ('1', '2'):
    hdr += [f'mcrad{th}T', f'batch{th}T', f'lifted{th}T', f'Embree{th}T', f'obvhs{th}T', f'm/E{th}T', f'b/E{th}T', f'l/E{th}T']
out = [hdr]
for (scene, query), d in rows.items():
    r = [scene, q_short.get(query, query)]
    for th in ('1', '2'):
        kv = d.get(th)
        # 'mcrad-lifted' (closest only; older outputs lack it): '-' where absent or NaN
        f = lambda k, p: '-' if k not in kv or kv[k].lower() == 'nan' else f"{float(kv[k]):.{p}f}"
        if kv is None:
            r += ['-'] * 8
        else:
            r += [f(k, 2) for k in ('mcrad', 'mcrad-batch', 'mcrad-lifted', 'embree', 'obvhs')]
            r += [f(k, 3) for k in ('ratio_mcrad', 'ratio_batch', 'ratio_lifted')]
    out.append(r)
wid = [max(len(x[i]) for x in out) for i in range(len(hdr))]
print('Mrays/s (wall, median of rounds with >=90% CPU efficiency); m/E, b/E, l/E = median per-round mcrad/Embree, mcrad-batch/Embree, mcrad-lifted/Embree')
print('lifted = mcrad on the very rays Embree gets: closest, Ray::from_surface(file origin 1e-3 above src, unit ccw normal, dir, src); occluded, SurfacePoint::free of both lifted ends')
print('occl-facing = occlusion of the pairs whose ends face each other (the end triangles block neither engine)')
for r in out:
    print('  '.join(x.rjust(wid[i]) for i, x in enumerate(r)))
print()
out = [['scene', 'mcrad build 1T ms', '2T ms', 'Embree-med 1T ms', '2T ms', 'obvhs-fast 1T ms', '2T ms', 'mcrad bytes/tri', 'id==Embree same-line', 'id==Embree surface']]
for s, kv in builds.items():
    out.append([s, kv['mcrad_1T_ms'], kv['mcrad_2T_ms'], kv['embree_medium_1T_ms'], kv['embree_medium_2T_ms'],
                kv['obvhs_fast_1T_ms'], kv['obvhs_fast_2T_ms'], kv['bytes_per_tri'],
                agree.get((s, 'closest-same-line:'), '?'), agree.get((s, 'closest:'), '?')])
wid = [max(len(x[i]) for x in out) for i in range(len(out[0]))]
for r in out:
    print('  '.join(x.rjust(wid[i]) for i, x in enumerate(r)))
EOF
}
if [ -n "${TABLE_ONLY:-}" ]; then table "$TABLE_ONLY"; exit 0; fi

MCRAD_RAYCAST=${MCRAD_RAYCAST:-$(cd "$HERE/../.." && pwd)}
export CARGO_TARGET_DIR=$B/target
OUT=${OUT:-$B/results-$(date +%Y%m%d-%H%M%S).txt}
read -r -a CORNELL_A <<< "${CORNELL:-3 5000000}"
read -r -a ROOM100K_A <<< "${ROOM100K:-3 1500000}"
read -r -a ROOM1M_A <<< "${ROOM1M:-3 1000000}"

cd $B/src
sed -i "s|^mcrad-raycast = .*|mcrad-raycast = { path = \"$MCRAD_RAYCAST\" }|" Cargo.toml
sed -i '/^mcrad-raycast-main = /d' Cargo.toml
FEATURES=embree
if [ -n "${MAIN_REV:-}" ]; then
  # a copy of the repository at MAIN_REV, its ray caster renamed so that both link into rbench
  REPO=$(cd "$MCRAD_RAYCAST/../.." && pwd)
  rm -rf "$B/mcrad-main" && mkdir -p "$B/mcrad-main"
  git -C "$REPO" archive "$MAIN_REV" | tar -x -C "$B/mcrad-main"
  sed -i 's/^name = "mcrad-raycast"$/name = "mcrad-raycast-main"/' "$B/mcrad-main/crates/raycast/Cargo.toml"
  sed -i "s|^mcrad-raycast = .*|&\nmcrad-raycast-main = { path = \"$B/mcrad-main/crates/raycast\" }|" Cargo.toml
  FEATURES=main-copy
fi
echo "building against $MCRAD_RAYCAST${MAIN_REV:+ and $MAIN_REV}" >&2
if ! cargo build --release --features $FEATURES > $B/build.log 2>&1; then
  tail -40 $B/build.log >&2; echo "build FAILED (full log: $B/build.log)" >&2; exit 1
fi
grep -E 'Compiling mcrad|Finished' $B/build.log >&2 || true
[ -f $B/data/room1m.vis.rays ] || $CARGO_TARGET_DIR/release/rbench gen $B/data 10000000

if [ -n "${MAIN_REV:-}" ]; then
  read -r -a OCCL_ROOMS_A <<< "${OCCL_ROOMS:-40 1000000 50000}"
  read -r -a OCCL_CORNELL_A <<< "${OCCL_CORNELL:-30 1000000 100000}"
  {
    echo "# $(date -u +%FT%TZ) mcrad-raycast=$MCRAD_RAYCAST against $MAIN_REV ($(git -C "$REPO" rev-parse --short "$MAIN_REV"))"
    echo "# loadavg before: $(cat /proc/loadavg)"
    CLOSEST=1 $CARGO_TARGET_DIR/release/rbench occl $B/data room100k "${OCCL_ROOMS_A[@]}" 1,2
    CLOSEST=1 $CARGO_TARGET_DIR/release/rbench occl $B/data room1m "${OCCL_ROOMS_A[@]}" 1,2
    CLOSEST=1 $CARGO_TARGET_DIR/release/rbench occl $B/data cornell "${OCCL_CORNELL_A[@]}" 1,2
    echo "# loadavg after: $(cat /proc/loadavg)"
  } > "$OUT"
  echo "raw output: $OUT"
  grep -E '^(OCCL|ANSWERS)' "$OUT" | tee "$OUT.table"
  exit 0
fi
{
  echo "# $(date -u +%FT%TZ) mcrad-raycast=$MCRAD_RAYCAST $( (cd "$MCRAD_RAYCAST" && git rev-parse --short HEAD 2>/dev/null && git status --short . 2>/dev/null | wc -l | sed 's/$/ uncommitted files/') | tr '\n' ' ') $(cat "$MCRAD_RAYCAST/../../HEAD_COMMIT" 2>/dev/null | sed 's/^/snapshot of commit /')"
  echo "# loadavg before: $(cat /proc/loadavg)"
  $CARGO_TARGET_DIR/release/rbench compare $B/data cornell "${CORNELL_A[@]}" 1,2
  $CARGO_TARGET_DIR/release/rbench compare $B/data room100k "${ROOM100K_A[@]}" 1,2
  $CARGO_TARGET_DIR/release/rbench compare $B/data room1m "${ROOM1M_A[@]}" 1,2
  echo "# loadavg after: $(cat /proc/loadavg)"
} > "$OUT"
echo "raw output: $OUT"
table "$OUT" | tee "$OUT.table"
