// Bird's-eye renderer shaders: ground (patterns, lines), sensor sectors, vehicles, id labels.
// Positions arrive in metres relative to the view centre; `g.scale` maps them to clip space.
// Colours are sRGB values in 0..1 throughout and blending happens in sRGB space, as in most 2D
// renderers: it avoids a linear<->sRGB conversion per blended pixel, which dominates the frame
// time on a software rasteriser.

struct Globals {
    // metres -> clip space: (2P/W, 2P·aspect/H)
    scale: vec2<f32>,
    // image size [px]
    viewport: vec2<f32>,
    // horizontal pixels per metre
    ppm: f32,
    _pad0: f32,
    _pad1: f32,
    _pad2: f32,
};

@group(0) @binding(0) var<uniform> g: Globals;
@group(0) @binding(1) var patterns: texture_2d_array<f32>;
@group(0) @binding(2) var pattern_sampler: sampler;
@group(0) @binding(3) var font: texture_2d<f32>;

// Two triangles of a quad, corners in [0,1]^2.
fn quad_corner(vi: u32) -> vec2<f32> {
    var corners = array<vec2<f32>, 6>(
        vec2<f32>(0.0, 0.0), vec2<f32>(1.0, 0.0), vec2<f32>(1.0, 1.0),
        vec2<f32>(0.0, 0.0), vec2<f32>(1.0, 1.0), vec2<f32>(0.0, 1.0),
    );
    return corners[vi];
}

fn rotate(v: vec2<f32>, dir: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(v.x * dir.x - v.y * dir.y, v.x * dir.y + v.y * dir.x);
}

fn to_clip(rel: vec2<f32>) -> vec4<f32> {
    return vec4<f32>(rel * g.scale, 0.0, 1.0);
}

// ---- ground: patterns inside polygons, anti-aliased and dashed lines ----

struct GroundOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) tex: vec3<f32>,
    @location(1) color: vec4<f32>,
    @location(2) line: vec4<f32>,
};

@vertex
fn vs_ground(@location(0) pos: vec2<f32>, @location(1) tex: vec3<f32>, @location(2) color: vec4<f32>,
             @location(3) line: vec4<f32>) -> GroundOut {
    var out: GroundOut;
    out.clip = to_clip(pos);
    out.tex = tex;
    out.color = color;
    out.line = line;
    return out;
}

@fragment
fn fs_ground(in: GroundOut) -> @location(0) vec4<f32> {
    let layer = max(i32(round(in.tex.z)), 0);
    var t = textureSample(patterns, pattern_sampler, in.tex.xy, layer);
    // Hide the tile repetition: modulate brightness by the same pattern sampled 7.3x larger,
    // rotated and blurred (mip level 4, 16x16 texels, so joints and lugs do not show), relative
    // to the pattern's mean colour (its 1x1 mip level).
    let big_uv = mat2x2<f32>(0.8, 0.6, -0.6, 0.8) * in.tex.xy * 0.137;
    let big = textureSampleLevel(patterns, pattern_sampler, big_uv, layer, 4.0);
    let mean = textureSampleLevel(patterns, pattern_sampler, vec2<f32>(0.5), layer, 16.0);
    let luma = vec3<f32>(0.2126, 0.7152, 0.0722);
    let ratio = clamp(dot(big.rgb, luma) / max(dot(mean.rgb, luma), 1e-4), 0.5, 1.6);
    t = vec4<f32>(t.rgb * mix(1.0, ratio, 0.45), t.a);
    var c = select(in.color, in.color * t, in.tex.z >= 0.0);
    if (in.line.y > 0.0) {
        // coverage of a line of half width line.y [px] at distance |line.x| [px] from its axis
        c.a = c.a * clamp(in.line.y + 0.5 - abs(in.line.x), 0.0, 1.0);
        if (in.line.w > 0.0 && fract(in.line.z / in.line.w) >= 0.5) {
            discard;
        }
    }
    return c;
}

// ---- sensor sectors: radar cones, velodyne and wifi circles ----

struct SectorOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) local: vec2<f32>,
    @location(1) @interpolate(flat) shape: vec2<f32>,
    @location(2) color: vec4<f32>,
};

struct Sector {
    pos: vec2<f32>,
    dir: vec2<f32>,
    range: f32,
    half_angle: f32,
    color: u32,
    _pad: u32,
};

struct Vehicle {
    pos: vec2<f32>,
    dir: vec2<f32>,
    size: vec2<f32>,
    color: u32,
    real: u32,
};

struct Label {
    anchor: vec2<f32>,
    offset: vec2<f32>,
    glyphs: vec2<u32>,
    count: u32,
    color: u32,
    scale: f32,
    _pad: u32,
};

// Per-frame items, read by vertex pulling: item vi / 6, quad corner vi % 6. One plain draw of
// 6·N vertices replaces N hardware instances, which cost several µs each on lavapipe.
@group(1) @binding(0) var<storage, read> sectors: array<Sector>;
@group(1) @binding(1) var<storage, read> vehicles: array<Vehicle>;
@group(1) @binding(2) var<storage, read> labels: array<Label>;

@vertex
fn vs_sector(@builtin(vertex_index) vi: u32) -> SectorOut {
    let item = sectors[vi / 6u];
    let pos = item.pos;
    let dir = item.dir;
    let range = item.range;
    let half_angle = item.half_angle;
    let color = unpack4x8unorm(item.color);
    var out: SectorOut;
    let m = 2.0 / g.ppm;
    // the smallest box around the sector: a cone narrower than a half disc lies ahead only
    var lo = vec2<f32>(-range - m);
    var hi = vec2<f32>(range + m);
    if (half_angle < 1.5707963) {
        let side = range * sin(half_angle) + m;
        lo = vec2<f32>(-m, -side);
        hi = vec2<f32>(range + m, side);
    }
    let local = mix(lo, hi, quad_corner(vi % 6u));
    out.clip = to_clip(pos + rotate(local, dir));
    out.local = local;
    out.shape = vec2<f32>(range, half_angle);
    out.color = color;
    return out;
}

@fragment
fn fs_sector(in: SectorOut) -> @location(0) vec4<f32> {
    let d = length(in.local);
    let range = in.shape.x;
    let half_angle = in.shape.y;
    let ang = abs(atan2(in.local.y, in.local.x));
    let px = 1.0 / g.ppm;
    if (d > range || ang > half_angle) {
        discard;
    }
    // distance to the rim and, for a cone, to its straight edges [m]
    var edge = range - d;
    if (half_angle < 3.14) {
        let off = half_angle - ang;
        edge = min(edge, select(d, d * sin(off), off < 1.5707963));
    }
    // a faint fill fading outwards, so many overlapping ranges stay readable, and a firm rim
    var a = in.color.a * (1.0 - 0.6 * d / range);
    if (edge < 1.5 * px) {
        a = 0.7;
    }
    return vec4<f32>(in.color.rgb, a);
}

// ---- vehicles: oriented bodies with cab, windscreen and lights ----

struct VehicleOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) local: vec2<f32>,
    @location(1) @interpolate(flat) size: vec2<f32>,
    @location(2) @interpolate(flat) color: vec4<f32>,
    @location(3) @interpolate(flat) real: u32,
    @location(4) @interpolate(flat) shadow: vec2<f32>,
};

// Soft shadow as if lit from the upper left: offset [m] in the world and blur [m].
const SHADOW_OFFSET: vec2<f32> = vec2<f32>(0.15, -0.22);
const SHADOW_BLUR: f32 = 0.15;
// Scale [px/m] below which vehicles have no shadow.
const SHADOW_MIN_PPM: f32 = 8.0;

@vertex
fn vs_vehicle(@builtin(vertex_index) vi: u32) -> VehicleOut {
    let item = vehicles[vi / 6u];
    let pos = item.pos;
    let dir = item.dir;
    let size = item.size;
    let color = unpack4x8unorm(item.color);
    var out: VehicleOut;
    // never smaller than 4 px, so a vehicle stays visible when zoomed far out
    let sz = max(size, vec2<f32>(4.0 / g.ppm));
    let px = 1.0 / g.ppm;
    // the body, its shadow and one pixel more on every side for the anti-aliased edge; below
    // SHADOW_MIN_PPM the shadow would be a pixel wide and is left out (it would double the pixels)
    let shadow_reach = select(0.0, length(SHADOW_OFFSET) + max(SHADOW_BLUR, px), g.ppm >= SHADOW_MIN_PPM);
    let grow = shadow_reach + px;
    let local = (quad_corner(vi % 6u) - vec2<f32>(0.5)) * (sz + vec2<f32>(2.0 * grow));
    out.clip = to_clip(pos + rotate(local, dir));
    out.local = local;
    out.size = sz;
    out.color = color;
    out.real = item.real;
    // the world-fixed shadow offset in the vehicle's frame
    out.shadow = rotate(SHADOW_OFFSET, vec2<f32>(dir.x, -dir.y));
    return out;
}

@fragment
fn fs_vehicle(in: VehicleOut) -> @location(0) vec4<f32> {
    let len = in.size.x;
    let wid = in.size.y;
    let px = 1.0 / g.ppm;
    let side = 0.5 * wid - abs(in.local.y);
    let edge = min(0.5 * len - abs(in.local.x), side);
    // coverage of the body (edge < 0 outside it) and of its shadow
    let cover = clamp(edge * g.ppm + 0.5, 0.0, 1.0);
    let d = abs(in.local - in.shadow) - 0.5 * in.size;
    let outside = length(max(d, vec2<f32>(0.0))) + min(max(d.x, d.y), 0.0);
    let shade = select(0.0, 0.4 * clamp(0.5 - outside / max(SHADOW_BLUR, px), 0.0, 1.0), g.ppm >= SHADOW_MIN_PPM);
    let a = cover + (1.0 - cover) * shade;
    if (a < 0.004) {
        discard;
    }
    let border = max(0.07 * wid, 1.2 * px);
    let d_front = 0.5 * len - in.local.x;
    var c = in.color.rgb;
    if (d_front < 0.2 * len) {
        // cab / bonnet, a shade lighter
        c = min(c * 1.12 + vec3<f32>(0.05), vec3<f32>(1.0));
    }
    if (d_front > 0.2 * len && d_front < 0.3 * len && side > 1.5 * border) {
        // windscreen
        c = vec3<f32>(0.19, 0.25, 0.31);
    }
    if (d_front < 0.06 * len && side < 0.3 * wid && side > border) {
        // headlights
        c = vec3<f32>(1.0, 0.96, 0.8);
    }
    // indicator (a lane change in progress): amber front and rear corners on its side
    let ind_side = select(select(0.0, -1.0, (in.real & 8u) != 0u), 1.0, (in.real & 4u) != 0u);
    let corner = max(0.18 * min(len, 2.5 * wid), 2.0 * px);
    if (ind_side != 0.0 && in.local.y * ind_side > 0.5 * wid - corner
        && (d_front < corner || 0.5 * len + in.local.x < corner) && edge > 0.0) {
        return vec4<f32>(vec3<f32>(1.0, 0.62, 0.0) * cover / a, a);
    }
    if ((in.real & 2u) != 0u && d_front > 0.36 * len && d_front < 0.36 * len + max(0.14 * len, 3.0 * px)
        && side > border) {
        // light bar of an emergency vehicle: red on its left half, blue on its right
        c = select(vec3<f32>(0.1, 0.3, 1.0), vec3<f32>(1.0, 0.1, 0.1), in.local.y > 0.0);
    } else if ((in.real & 1u) == 0u) {
        // virtual vehicles: diagonal hatching and a light outline
        if (fract((in.local.x + in.local.y) / max(0.6, 5.0 * px)) < 0.5) {
            c = mix(c, vec3<f32>(1.0), 0.35);
        }
        if (edge < border) {
            c = vec3<f32>(0.96);
        }
    } else if (edge < border) {
        c = vec3<f32>(0.1);
    }
    // body over shadow (black): premultiplied sum divided by the combined alpha
    return vec4<f32>(c * cover / a, a);
}

// ---- id labels: one quad per label, white glyphs from the 5x7 font atlas with an outline ----

struct LabelOut {
    @builtin(position) clip: vec4<f32>,
    // position inside the label [font px]
    @location(0) cell: vec2<f32>,
    @location(1) @interpolate(flat) glyphs: vec2<u32>,
    @location(2) @interpolate(flat) count: u32,
    @location(3) color: vec4<f32>,
};

// Padding around the text, where the outline goes [font px]; keep in step with LABEL_PAD in sprites.rs.
const LABEL_PAD: f32 = 1.0;

@vertex
fn vs_label(@builtin(vertex_index) vi: u32) -> LabelOut {
    let item = labels[vi / 6u];
    let anchor = item.anchor;
    let offset = item.offset;
    let count = item.count;
    var out: LabelOut;
    let ndc = anchor * g.scale;
    // snap the anchor to whole pixels so the glyphs stay crisp
    let anchor_px = floor(vec2<f32>(ndc.x + 1.0, 1.0 - ndc.y) * 0.5 * g.viewport);
    let cells = vec2<f32>(f32(count) * 6.0 - 1.0, 7.0) + vec2<f32>(2.0 * LABEL_PAD);
    let corner = quad_corner(vi % 6u);
    let p = anchor_px + offset + corner * cells * item.scale;
    out.clip = vec4<f32>(p.x / g.viewport.x * 2.0 - 1.0, 1.0 - p.y / g.viewport.y * 2.0, 0.0, 1.0);
    out.cell = corner * cells;
    out.glyphs = item.glyphs;
    out.count = count;
    out.color = unpack4x8unorm(item.color);
    return out;
}

// Whether the text pixel (x, y) [font px, from the text's top-left] is ink.
fn label_ink(x: i32, y: i32, glyphs: vec2<u32>, count: u32) -> bool {
    if (x < 0 || y < 0 || y >= 7) {
        return false;
    }
    let i = x / 6;
    let col = x - 6 * i;
    if (i >= i32(count) || col >= 5) {
        return false;
    }
    // glyph indices are packed 4 bits each, 8 per word
    let word = select(glyphs.x, glyphs.y, i >= 8);
    let glyph = (word >> (4u * u32(i % 8))) & 15u;
    return textureLoad(font, vec2<i32>(i32(glyph) * 5 + col, y), 0).r > 0.5;
}

@fragment
fn fs_label(in: LabelOut) -> @location(0) vec4<f32> {
    let t = floor(in.cell - vec2<f32>(LABEL_PAD));
    let x = i32(t.x);
    let y = i32(t.y);
    if (label_ink(x, y, in.glyphs, in.count)) {
        return vec4<f32>(1.0, 1.0, 1.0, 1.0);
    }
    // the outline: any of the 8 neighbours inked
    for (var dy = -1; dy <= 1; dy++) {
        for (var dx = -1; dx <= 1; dx++) {
            if (label_ink(x + dx, y + dy, in.glyphs, in.count)) {
                return in.color;
            }
        }
    }
    // a faint backing, so the outline reads on busy ground
    return vec4<f32>(in.color.rgb, 0.3 * in.color.a);
}
