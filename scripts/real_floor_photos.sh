#!/usr/bin/env bash
# The four real floor photographs that real_floor_small_test reads, taken from the Debian
# packages that hold them (apt-get download: nothing is installed), with each package's
# copyright file beside them. For a clone with nothing beside it; the full set of photographs
# (make benchmark-real) is REAL_FLOORS.
#   ufoai-textures  (GPL-2):     concrete_g_9.jpg (smooth concrete), street001.png,
#                                street002.png (asphalt), inside base/0textures.pk3
#   redeclipse-data (CC-BY-3.0): trak4/plaster1.jpg (smooth concrete)
# Usage: real_floor_photos.sh OUT_DIR  (does nothing when OUT_DIR already holds them)
set -euo pipefail
out="$1"
want=(ufoai-textures_concrete_g_9.jpg ufoai-textures_street001.png ufoai-textures_street002.png
      redeclipse-data_plaster1.jpg)
have=1
for f in "${want[@]}"; do [ -s "$out/$f" ] || have=0; done
[ $have = 1 ] && exit 0
tmp="$out.partial"
rm -rf "$tmp"
mkdir -p "$tmp/debs" "$tmp/x"
echo "real floor photographs: downloading ufoai-textures and redeclipse-data (about 1.2 GB) to take 4 files"
(cd "$tmp/debs" && apt-get download -q ufoai-textures redeclipse-data > /dev/null) || {
  echo "real_floor_photos.sh: apt-get download failed (run apt-get update, or give the photographs with -DGTBOW_REAL_FLOORS=DIR)" >&2
  exit 1
}
dpkg-deb --fsys-tarfile "$tmp"/debs/ufoai-textures_*.deb |
  tar -x -C "$tmp/x" ./usr/share/games/ufoai/base/0textures.pk3 ./usr/share/doc/ufoai-textures/copyright
dpkg-deb --fsys-tarfile "$tmp"/debs/redeclipse-data_*.deb |
  tar -x -C "$tmp/x" ./usr/share/games/redeclipse/data/trak/trak4/plaster1.jpg \
    ./usr/share/doc/redeclipse-data/copyright
/usr/bin/python3 - "$tmp" <<'PY'
import sys, zipfile
tmp = sys.argv[1]
z = zipfile.ZipFile(tmp + "/x/usr/share/games/ufoai/base/0textures.pk3")
for inner, name in [("textures/tex_ctp1/concrete_g_9.jpg", "concrete_g_9.jpg"),
                    ("textures/tex_streets/street001.png", "street001.png"),
                    ("textures/tex_streets/street002.png", "street002.png")]:
    with open(tmp + "/ufoai-textures_" + name, "wb") as f:
        f.write(z.read(inner))
PY
cp "$tmp/x/usr/share/games/redeclipse/data/trak/trak4/plaster1.jpg" "$tmp/redeclipse-data_plaster1.jpg"
cp "$tmp/x/usr/share/doc/ufoai-textures/copyright" "$tmp/ufoai-textures.copyright"
cp "$tmp/x/usr/share/doc/redeclipse-data/copyright" "$tmp/redeclipse-data.copyright"
rm -rf "$tmp/debs" "$tmp/x"
rm -rf "$out"
mv "$tmp" "$out"
echo "real floor photographs: ${want[*]} in $out"
