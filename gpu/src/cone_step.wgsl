// Reference shader: cone stepping through terrabake's exported cone planes
// (docs/ENGINES.md, `export --layer cone_slope -o cones.ktx2`), one ray per
// invocation, in f32.
//
// Grid space, as terrabake_format::trace::Tracer::grid_ray gives it: u east
// in cells from the west edge, v south in rows from the north edge, z in
// metres. Cell (c, r) spans u in [c, c + 1], v in [r, r + 1]; its surface is
// two triangles split along the south-west to north-east diagonal
// (terrabake_format::surface); a cell with a nodata corner has none.
//
// The march: in the cell the ray is over, test the two triangles over the
// stretch until the ray leaves the cell; where it leaves, sample the cone
// texture bilinearly (texel centres at cell centres, clamped at the edges:
// what a sampler with linear filtering does) and leap as far as the ray stays
// inside the cone from that point. The exported texture is dilated (each
// texel the highest apex and least slope of its 3 x 3 cells), which makes
// every filtered cone empty of terrain, so a leap never passes a hit.
//
// The shading: at the hit, the share of the sun's disc above the horizon of
// the nearest post, from the exported horizon array (`export --layer
// horizon -o horizons.ktx2`: 16-bit codes, degrees = offset + scale * code,
// 0 nodata), linear between the two bands either side of the sun's azimuth,
// the disc cut by a straight horizon (terrabake_format::horizons).

struct Params {
    cells_x: u32,
    cells_y: u32,
    posts_x: u32,
    rays: u32,
    dx: f32,
    dy: f32,
    max_steps: u32,
    // Horizon bands (0: no shading), the sun, and the codes' decoding.
    bands: u32,
    sun_azimuth: f32,
    sun_elevation: f32,
    sun_radius: f32,
    horizon_offset: f32,
    horizon_scale: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
};

// Grid-space origin (u, v, z) and t_max; direction (du, dv, dz).
struct Ray {
    origin: vec4<f32>,
    dir: vec4<f32>,
};

struct Hit {
    t: f32,
    // c + r * cells.x, or 0xffffffff for a miss.
    cell: u32,
    // Cells whose triangles were tested, and leaps taken.
    cells_tested: u32,
    leaps: u32,
    // The sun's lit share at the hit, or -1 (a miss, nodata, no horizons).
    lit: f32,
};

@group(0) @binding(0) var<uniform> P: Params;
// Heights, posts row by row from the north; nodata as -3.0e38.
@group(0) @binding(1) var<storage, read> heights: array<f32>;
// The exported cone texture: (apex, slope) per cell.
@group(0) @binding(2) var<storage, read> cones: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read> rays: array<Ray>;
@group(0) @binding(4) var<storage, read_write> hits: array<Hit>;
// The horizon array's codes, band after band, one per post (widened to u32).
@group(0) @binding(5) var<storage, read> horizon: array<u32>;
// The bands' compass azimuths, degrees, ascending.
@group(0) @binding(6) var<storage, read> azimuths: array<f32>;

const NODATA: f32 = -1.0e38;
const MISS: u32 = 0xffffffffu;

fn post(c: i32, r: i32) -> f32 {
    return heights[u32(r) * P.posts_x + u32(c)];
}

fn texel(c: i32, r: i32) -> vec2<f32> {
    let cc = clamp(c, 0, i32(P.cells_x) - 1);
    let rr = clamp(r, 0, i32(P.cells_y) - 1);
    return cones[u32(rr) * P.cells_x + u32(cc)];
}

// The filtered cone at grid point q.
fn cone_at(q: vec2<f32>) -> vec2<f32> {
    let s = q - vec2<f32>(0.5, 0.5);
    let i = floor(s);
    let f = s - i;
    let c = i32(i.x);
    let r = i32(i.y);
    let top = mix(texel(c, r), texel(c + 1, r), f.x);
    let bottom = mix(texel(c, r + 1), texel(c + 1, r + 1), f.x);
    return mix(top, bottom, f.y);
}

// The triangle's height at (east, north) fractions of cell (c, r).
fn surface(c: i32, r: i32, e: f32, n: f32) -> f32 {
    let nw = post(c, r);
    let ne = post(c + 1, r);
    let sw = post(c, r + 1);
    let se = post(c + 1, r + 1);
    let ec = clamp(e, 0.0, 1.0);
    let nc = clamp(n, 0.0, 1.0);
    if (ec >= nc) {
        return sw + ec * (se - sw) + nc * (ne - se);
    }
    return sw + nc * (nw - sw) + ec * (ne - nw);
}

// The first t in [t0, t1] where the ray is at or below cell (c, r)'s
// surface, or -1.
fn intersect_cell(o: vec3<f32>, d: vec3<f32>, c: i32, r: i32, t0: f32, t1: f32) -> f32 {
    let nw = post(c, r);
    let ne = post(c + 1, r);
    let sw = post(c, r + 1);
    let se = post(c + 1, r + 1);
    if (min(min(nw, ne), min(sw, se)) < NODATA) {
        return -1.0;
    }
    // Above the tallest corner all along: no hit.
    let top = max(max(nw, ne), max(sw, se));
    if (min(o.z + t0 * d.z, o.z + t1 * d.z) > top) {
        return -1.0;
    }
    let cu = f32(c);
    let rv = f32(r);
    let g0 = (o.x + t0 * d.x - cu) - (rv + 1.0 - (o.y + t0 * d.y));
    let g1 = (o.x + t1 * d.x - cu) - (rv + 1.0 - (o.y + t1 * d.y));
    var tm = t1;
    let split = (g0 < 0.0 && g1 > 0.0) || (g0 > 0.0 && g1 < 0.0);
    if (split) {
        tm = clamp(t0 + (t1 - t0) * (g0 / (g0 - g1)), t0, t1);
    }
    var a = t0;
    var b = tm;
    for (var part = 0; part < 2; part++) {
        if (part == 1) {
            if (!split) {
                break;
            }
            a = tm;
            b = t1;
        }
        let pa = o + a * d;
        let pb = o + b * d;
        let fa = pa.z - surface(c, r, pa.x - cu, rv + 1.0 - pa.y);
        let fb = pb.z - surface(c, r, pb.x - cu, rv + 1.0 - pb.y);
        if (fa <= 0.0) {
            return a;
        }
        if (fb <= 0.0) {
            return clamp(a + (b - a) * (fa / (fa - fb)), a, b);
        }
    }
    return -1.0;
}

fn wrap360(a: f32) -> f32 {
    return a - 360.0 * floor(a / 360.0);
}

// The horizon (degrees) of band b at post p, or a value below -1000 for nodata.
fn horizon_deg(b: u32, p: u32) -> f32 {
    let code = horizon[b * P.posts_x * (P.cells_y + 1u) + p];
    if (code == 0u) {
        return -2000.0;
    }
    return P.horizon_offset + P.horizon_scale * f32(code);
}

// The lit share of the sun's disc at post (x, y), or -1.
fn lit_at(x: u32, y: u32) -> f32 {
    let n = P.bands;
    if (n == 0u) {
        return -1.0;
    }
    let az = wrap360(P.sun_azimuth);
    var after = 0u;
    for (var b = 0u; b < n; b++) {
        if (azimuths[b] <= az) {
            after = b + 1u;
        }
    }
    let i = (after + n - 1u) % n;
    let j = after % n;
    let span = wrap360(azimuths[j] - azimuths[i]);
    var f = 0.0;
    if (span != 0.0) {
        f = wrap360(az - azimuths[i]) / span;
    }
    let p = y * P.posts_x + x;
    let h0 = horizon_deg(i, p);
    let h1 = horizon_deg(j, p);
    if (h0 < -1000.0 || h1 < -1000.0) {
        return -1.0;
    }
    // -90 is "nothing ahead", a marker: never blended with a real angle,
    // and on a band the band itself (terrabake_format::horizons::between).
    var h = h0 + f * (h1 - h0);
    if (f == 0.0) {
        h = h0;
    } else if (h0 == -90.0 && h1 != -90.0) {
        h = h1;
    } else if (h1 == -90.0 && h0 != -90.0) {
        h = h0;
    }
    if (P.sun_radius <= 0.0) {
        return select(0.0, 1.0, P.sun_elevation > h);
    }
    let d = clamp((P.sun_elevation - h) / P.sun_radius, -1.0, 1.0);
    return 1.0 - (acos(d) - d * sqrt(1.0 - d * d)) / 3.14159265358979;
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let k = id.x;
    if (k >= P.rays) {
        return;
    }
    let o = rays[k].origin.xyz;
    let d = rays[k].dir.xyz;
    var hit = Hit(0.0, MISS, 0u, 0u, -1.0);
    // The stretch of the ray over the DEM (slabs).
    let size = vec2<f32>(f32(P.cells_x), f32(P.cells_y));
    var ta = 0.0;
    var tb = rays[k].origin.w;
    for (var axis = 0; axis < 2; axis++) {
        let lo = (0.0 - o[axis]) / d[axis];
        let hi = (size[axis] - o[axis]) / d[axis];
        if (d[axis] == 0.0) {
            if (o[axis] < 0.0 || o[axis] > size[axis]) {
                tb = -1.0;
            }
        } else {
            ta = max(ta, min(lo, hi));
            tb = min(tb, max(lo, hi));
        }
    }
    // Horizontal metres and metres of rise per unit of t.
    let run = length(vec2<f32>(d.x * P.dx, d.y * P.dy));
    let rise = d.z;
    var t = ta;
    for (var step = 0u; step < P.max_steps && t <= tb; step++) {
        let p = o + t * d;
        // The cell the ray is over just after t.
        let ahead = p.xy + d.xy * 1e-4;
        let c = clamp(i32(floor(ahead.x)), 0, i32(P.cells_x) - 1);
        let r = clamp(i32(floor(ahead.y)), 0, i32(P.cells_y) - 1);
        // Where it leaves the cell.
        var t1 = tb;
        if (d.x > 0.0) { t1 = min(t1, (f32(c + 1) - o.x) / d.x); }
        if (d.x < 0.0) { t1 = min(t1, (f32(c) - o.x) / d.x); }
        if (d.y > 0.0) { t1 = min(t1, (f32(r + 1) - o.y) / d.y); }
        if (d.y < 0.0) { t1 = min(t1, (f32(r) - o.y) / d.y); }
        t1 = max(t1, t);
        hit.cells_tested += 1u;
        let th = intersect_cell(o, d, c, r, t, t1);
        if (th >= 0.0) {
            hit.t = th;
            hit.cell = u32(r) * P.cells_x + u32(c);
            // Shade from the nearest post's horizon.
            let at = o + th * d;
            let x = u32(clamp(round(at.x), 0.0, f32(P.cells_x)));
            let y = u32(clamp(round(at.y), 0.0, f32(P.cells_y)));
            hit.lit = lit_at(x, y);
            break;
        }
        // Leap inside the filtered cone where the ray leaves the cell.
        let q = o + t1 * d;
        let cone = cone_at(q.xy);
        let above = q.z - cone.x - abs(q.z) * 1e-6;
        var next = t1;
        if (above > 0.0 && cone.y > 0.0) {
            let closing = run - cone.y * rise;
            if (closing <= 0.0) {
                // Rising at least as fast as the cone widens: never meets terrain.
                break;
            }
            next = t1 + cone.y * above / closing * 0.999;
            hit.leaps += 1u;
        }
        // Always forward: at least past the cell edge by a hair.
        t = max(next, t1 + max(abs(t1), 1.0) * 1e-6);
    }
    hits[k] = hit;
}
