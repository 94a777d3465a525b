//! The sensor tick ([`sense_vehicles`]): the grid rebuilt or the neighbour lists kept, and the
//! vehicles sensed in chunks over the threads.

use bevy_ecs::prelude::{Has, Local, Query, Res, ResMut};

use super::errors::{Draws, Footprint, occludes};
use super::readings::SensorStats;
use super::scan::{Listing, SenseInput, SenseScratch, SensingTable, sense_chunk, sense_listed};
use crate::sim::grid::lists::{
    Everyone, ListFloor, Lists, NearWanted, NeighbourLists, Neighbours, SKIN_SHARE, SensorGrid, Shape, ShapeSummary,
    bounded, typical_range,
};
use crate::sim::{GridEntry, Parallelism, SimClock, SimSeed, SpatialGrid};
use crate::world::{
    Omniscient, Radar, SensorErrors, SensorReadings, SimTime, VehicleId, VehicleSize, VehicleState, Velodyne,
};

/// Rebuild the sensor grid and fill every sensing vehicle's [`SensorReadings`], nearest first.
///
/// The grid's cells are as large as the median bounded range, so a typical vehicle sees only
/// vehicles of its own cell and the eight around it, and one of longer range searches as many
/// cells around it as its range reaches. Vehicles are visited in query order (spawn order,
/// which keeps each one's components in cache lines next to the previous one's); the candidates
/// around a cell are gathered into a small buffer and reused while consecutive vehicles share
/// that cell. The vehicles are cut into contiguous chunks over [`Parallelism::threads`]
/// threads; each vehicle's readings depend only on the grid and itself, so the split never
/// changes them.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub fn sense_vehicles(
    mut grid: ResMut<SensorGrid>,
    parallelism: Res<Parallelism>,
    clock: Res<SimClock>,
    seed: Option<Res<SimSeed>>,
    mut stats: ResMut<SensorStats>,
    everyone: EveryoneQuery,
    mut sensing: SensingQuery,
    mut scratch: Local<Vec<SenseScratch>>,
    mut shape_parts: Local<Vec<ShapeSummary>>,
    mut ranges: Local<Vec<f64>>,
    mut footprints: Local<Vec<Footprint>>,
    asked: Option<Res<ListFloor>>,
    near_wanted: Option<Res<NearWanted>>,
) {
    let SensorGrid { grid, neighbours } = &mut *grid;
    if sensing.is_empty() {
        return;
    }
    let draws = Draws::new(seed.map_or(0, |s| s.0), clock.now.0);
    let floor = asked.map_or(0.0, |f| f.0);
    let near_r2 = (near_wanted.is_some_and(|w| w.0 == Some(clock.now)) && floor > 0.0).then_some(floor * floor);
    let input = (&*grid, draws, floor, near_r2);
    let kept =
        sense_with_kept_lists(neighbours, input, (*parallelism, clock.now), &everyone, &mut sensing, &mut scratch);
    if !kept {
        sense_by_shapes(
            (grid, neighbours),
            (*parallelism, clock.now),
            (draws, floor, near_r2),
            (&everyone, &mut sensing),
            (&mut scratch, &mut shape_parts, &mut ranges, &mut footprints),
        );
    }
    for s in scratch.iter_mut() {
        stats.add(&s.stats);
        s.stats = SensorStats::default();
    }
}

/// The query of the vehicles that sense ([`sense_vehicles`]).
pub(super) type SensingQuery<'w, 's> = Query<
    'w,
    's,
    (
        &'static VehicleId,
        &'static VehicleState,
        Option<&'static Radar>,
        Option<&'static Velodyne>,
        Has<Omniscient>,
        Option<&'static SensorErrors>,
        &'static mut SensorReadings,
    ),
>;

/// The query of every vehicle (the targets, [`sense_vehicles`]).
pub(super) type EveryoneQuery<'w, 's> =
    Query<'w, 's, (&'static VehicleId, &'static VehicleState, Option<&'static VehicleSize>)>;

/// Whether the sensing vehicles are one non-empty ECS table holding every vehicle, `ids` (those
/// of [`one_table`]), none of them omniscient: where the neighbour lists serve.
pub(super) fn senses_everyone(sensing: &SensingQuery<'_, '_>, ids: &[VehicleId]) -> bool {
    let readonly = sensing.as_readonly();
    let Ok(tables) = readonly.contiguous_iter() else { return false };
    let mut full = tables.filter(|t| !t.0.is_empty());
    match (full.next(), full.next()) {
        (Some((sensing_ids, _, _, _, omniscient, _, _)), None) => !omniscient && sensing_ids == ids,
        _ => false,
    }
}

/// The ids and states of the one non-empty ECS table of every vehicle, if they are all in one.
pub(super) fn one_table<'a>(everyone: &'a EveryoneQuery<'_, '_>) -> Option<(&'a [VehicleId], &'a [VehicleState])> {
    let mut full = everyone.contiguous_iter().ok()?.filter(|(ids, _, _)| !ids.is_empty());
    let (ids, states, _) = full.next()?;
    full.next().is_none().then_some((ids, states))
}

/// A sensor tick over the neighbour lists as they are, in one pass: each chunk of vehicles
/// senses from its lists and, beside that, adds up its displacements since the build and
/// checks that its sensors are the build's; the lists are kept when all hold
/// ([`NeighbourLists::drifted_together`]), else the tick is thrown away (nothing written but
/// the readings, the wifi masks and the counts in `scratch`, which the tick made again
/// overwrites and this resets) and `false` returned, for [`sense_by_shapes`] to build them.
/// The same readings as that path bit for bit: where the lists hold, it senses from the same
/// lists with the same sight.
///
/// That path finds the sensors' shapes and the displacements in two passes of their own over
/// the threads before sensing: two hand-overs to the helpers per tick, each of a few
/// microseconds' work per thousand vehicles, where the caller waited for a helper's late
/// start and its last chunk (10,000 vehicles, 2 threads, instrumented: the two passes and the
/// gaps before them were 7 % of a run). Lists are built every few seconds of simulated time;
/// a tick thrown away costs one tick's sensing then.
///
/// `input`: the grid, the tick's draws, the wifi range the lists must reach and, at a wifi
/// round's instant, its square ([`NearWanted`]).
pub(super) fn sense_with_kept_lists(
    neighbours: &mut Neighbours,
    (grid, draws, floor, near_r2): (&SpatialGrid, Draws, f64, Option<f64>),
    (parallelism, now): (Parallelism, SimTime),
    everyone: &EveryoneQuery<'_, '_>,
    sensing: &mut SensingQuery<'_, '_>,
    scratch: &mut Vec<SenseScratch>,
) -> bool {
    let lists = &mut neighbours.lists;
    if lists.skin <= 0.0 || lists.floor != floor || lists.kept_since_build < ONE_PASS_AFTER {
        return false;
    }
    let Some((ids, states)) = one_table(everyone) else { return false };
    let everyone = Everyone { ids, states };
    let n = ids.len();
    let built = |len: usize| len == n;
    let as_built = built(lists.cell_of.len()) && built(lists.headings.len()) && built(lists.shapes.len());
    if !as_built || !lists.of_vehicles(everyone) || lists.lists.len() != n {
        return false;
    }
    if !senses_everyone(sensing, ids) {
        return false;
    }
    let Ok(mut tables) = sensing.contiguous_iter_mut() else { return false };
    let Some((sensing_ids, sensing_states, radars, velodynes, omniscient, errors, mut readings)) =
        tables.find(|t| !t.0.is_empty())
    else {
        return false;
    };
    // Occlusion needs every vehicle's footprint ([`sense_by_shapes`] gathers them).
    if errors.is_some_and(|e| e.iter().any(occludes)) {
        return false;
    }
    let table = SensingTable { ids: sensing_ids, states: sensing_states, radars, velodynes, omniscient, errors };
    let input = SenseInput { grid, footprints: &[], draws };
    lists.size_near(n);
    let NeighbourLists { lists: kept, anchors, headings, cell_of, shapes, near, .. } = &mut *lists;
    let (kept, anchors, headings, cell_of, shapes) = (&*kept, &anchors[..], &headings[..], &cell_of[..], &shapes[..]);
    parallelism.for_each_chunk_pair_at(&mut readings, near, scratch, |start, chunk, near, s| {
        let r = start..start + chunk.len();
        let drift = &mut s.drift;
        drift.clear();
        drift.add(&anchors[r.clone()], &headings[r.clone()], &states[r.clone()], &cell_of[r.clone()]);
        let shape = |i: usize| Shape::of(radars.map(|x| &x[i]), velodynes.map(|v| &v[i]));
        s.shapes_held = r.into_iter().all(|i| shape(i) == shapes[i]);
        sense_listed(input, table, everyone, (Listing::Kept(kept), near_r2), (start, chunk, near), s);
    });
    let chunks = parallelism.chunks_for(n);
    let held = scratch.iter().take(chunks).all(|s| s.shapes_held)
        && lists.drifted_together(scratch.iter().take(chunks).map(|s| &s.drift), &mut neighbours.drift.boxes);
    if !held {
        scratch.iter_mut().for_each(|s| s.stats = SensorStats::default());
        lists.thrown_away += 1;
        return false;
    }
    lists.held_at = Some(now);
    if let Some(r2) = near_r2 {
        (lists.near_at, lists.near_r2) = (Some(now), r2);
    }
    lists.kept_in_one_pass += 1;
    lists.kept_since_build += 1;
    true
}

/// Sensor ticks that must have kept the lists since their build before one tries to keep them
/// in one pass ([`sense_with_kept_lists`]). A pass thrown away costs about a tick's sensing, a
/// kept one saves about a tenth of it (the two passes of [`sense_by_shapes`] and the waits
/// around them): where lists are built every few ticks (vehicles closing in fast, sensors
/// changed often), trying every tick would sense twice as often as it saves. With this many
/// first, builds every `ONE_PASS_AFTER` ticks or sooner never try, and the worst (one build
/// every `ONE_PASS_AFTER + 1` ticks) throws away a pass in that many ticks; traffic that moves
/// together builds every few seconds (hundreds of ticks) and loses only these first ticks.
pub(super) const ONE_PASS_AFTER: u32 = 8;

/// A sensor tick that first finds every vehicle's sensors ([`Shape`]) and the typical range,
/// then senses over the neighbour lists (kept if they hold, else built) or, where they cannot
/// serve, over the grid.
pub(super) fn sense_by_shapes(
    (grid, neighbours): (&mut SpatialGrid, &mut Neighbours),
    (parallelism, now): (Parallelism, SimTime),
    (draws, floor, near_r2): (Draws, f64, Option<f64>),
    (everyone, sensing): (&EveryoneQuery<'_, '_>, &mut SensingQuery<'_, '_>),
    (scratch, shape_parts, ranges, footprints): (
        &mut Vec<SenseScratch>,
        &mut Vec<ShapeSummary>,
        &mut Vec<f64>,
        &mut Vec<Footprint>,
    ),
) {
    ranges.clear();
    let mut occlusion = false;
    // Every sensing vehicle's sensors in query order (what the neighbour lists keep), and the
    // bounded ranges (for the typical range).
    let mut summary = ShapeSummary::default();
    let mut cell = None;
    if let Ok(tables) = sensing.as_readonly().contiguous_iter() {
        // Table by table, over the components' slices, split over the threads (a serial pass
        // every sensor tick before); each chunk sums up its shapes, merged in chunk order.
        let (shapes_now, built) = (&mut neighbours.shapes_now, &neighbours.lists.shapes);
        let mut end = 0;
        for (ids, _, radars, velodynes, _, errors, _) in tables {
            occlusion |= errors.is_some_and(|e| e.iter().any(occludes));
            let start = end;
            end += ids.len();
            // Longer only while the world grows: last tick's shapes are overwritten.
            if shapes_now.len() < end {
                shapes_now.resize(end, Shape::NONE);
            }
            let chunks = parallelism.chunks_for(ids.len());
            shape_parts.iter_mut().for_each(|p| *p = ShapeSummary::default());
            parallelism.for_each_chunk_at(&mut shapes_now[start..end], shape_parts, |k0, chunk, part| {
                let was = built.get(start + k0..).unwrap_or(&[]);
                for (k, shape) in chunk.iter_mut().enumerate() {
                    *shape = Shape::of(radars.map(|r| &r[k0 + k]), velodynes.map(|v| &v[k0 + k]));
                    part.add(shape);
                    part.as_built &= was.get(k) == Some(shape);
                }
            });
            shape_parts.iter().take(chunks).for_each(|part| summary.then(part));
        }
        shapes_now.truncate(end);
        summary.as_built &= built.len() == end;
        cell = summary.typical();
        if cell.is_none() {
            ranges.extend(shapes_now.iter().map(Shape::range).filter(bounded));
        }
    } else {
        neighbours.shapes_now.clear();
        summary.as_built = neighbours.lists.shapes.is_empty();
        ranges.extend(
            sensing
                .iter()
                .inspect(|item| occlusion |= item.5.is_some_and(occludes))
                .map(|(_, _, radar, velodyne, _, _, _)| Shape::of(radar, velodyne).range())
                .filter(bounded),
        );
    }
    footprints.clear();
    if occlusion {
        footprints.extend(everyone.iter().map(|(_, state, size)| {
            let size = size.copied().unwrap_or_default();
            Footprint { half_length: 0.5 * size.length, half_width: 0.5 * size.width, yaw: state.yaw }
        }));
    }
    let cell = cell.unwrap_or_else(|| typical_range(ranges));
    let entry = |i: usize, id: VehicleId, state: &VehicleState| GridEntry {
        position: state.position,
        velocity: state.velocity,
        id,
        index: i as u32,
    };
    // Split over the threads when every vehicle lies in one ECS table (the common case; the
    // tables a vehicle left when a component was added stay, empty; the index of each vehicle
    // is its place in query order either way).
    let one_table = one_table(everyone);
    // Neighbour lists when every vehicle senses, from that one table, with a bounded range.
    // (The shapes summed up above are then this one table's.)
    let listed = one_table
        .filter(|&(ids, _)| summary.finite && senses_everyone(sensing, ids))
        .map(|(ids, states)| Everyone { ids, states });
    if let Some(everyone) = listed {
        let skin = SKIN_SHARE * cell;
        let n = neighbours.shapes_now.len();
        let Neighbours { lists, shapes_now, drift, keys } = neighbours;
        // (At a wifi round's instant, `near_r2` notes who is within its range.)
        let build = !lists.hold(everyone, (summary.as_built, floor, skin), parallelism, drift);
        if build {
            grid.rebuild_on(parallelism, cell + skin, n, |i| entry(i, everyone.ids[i], &everyone.states[i]));
            lists.ids.clear();
            lists.ids.extend_from_slice(everyone.ids);
            lists.anchors.clear();
            lists.anchors.extend(everyone.states.iter().map(|s| s.position));
            lists.headings.clear();
            lists.headings.extend(everyone.states.iter().map(VehicleState::heading));
            lists.shapes.clear();
            lists.shapes.extend_from_slice(shapes_now);
            (lists.skin, lists.floor) = (skin, floor);
            lists.around = shapes_now.iter().map(|s| s.around(floor)).fold(f64::INFINITY, f64::min);
            lists.place_in_drift_cells(keys);
            lists.builds += 1;
            lists.kept_since_build = 0;
        } else {
            lists.kept_since_build = lists.kept_since_build.saturating_add(1);
        }
        let input = SenseInput { grid, footprints, draws };
        lists.size_near(n);
        let tables = sensing.contiguous_iter_mut().ok().into_iter().flatten();
        for (ids, states, radars, velodynes, omniscient, errors, mut readings) in tables {
            if ids.is_empty() {
                continue;
            }
            let table = SensingTable { ids, states, radars, velodynes, omniscient, errors };
            let listing = if build { Listing::Build { skin, floor } } else { Listing::Kept(&lists.lists) };
            parallelism.for_each_chunk_pair_at(&mut readings, &mut lists.near, scratch, |start, chunk, near, s| {
                sense_listed(input, table, everyone, (listing, near_r2), (start, chunk, near), s)
            });
        }
        if build {
            // Each chunk's lists, in chunk order, into the one array.
            let Lists { starts, neighbours } = &mut lists.lists;
            starts.clear();
            starts.push(0);
            neighbours.clear();
            // Scratch value k is chunk k's whichever thread ran it (`Parallelism::for_each_chunk`),
            // so the scratches are in chunk order already.
            debug_assert!(scratch.iter().filter_map(|s| s.built_from).is_sorted());
            for s in scratch.iter_mut().filter(|s| s.built_from.is_some()) {
                let base = neighbours.len() as u32;
                neighbours.extend_from_slice(&s.built);
                starts.extend(s.built_ends.iter().map(|&end| base + end));
                s.built_from = None;
            }
            debug_assert_eq!(starts.len(), n + 1);
        }
        lists.held_at = Some(now);
        if let Some(r2) = near_r2 {
            (lists.near_at, lists.near_r2) = (Some(now), r2);
        }
    } else {
        match one_table {
            Some((ids, states)) => {
                grid.rebuild_on(parallelism, cell, ids.len().min(states.len()), |i| entry(i, ids[i], &states[i]))
            }
            None => grid.rebuild(cell, everyone.iter().enumerate().map(|(i, (&id, state, _))| entry(i, id, state))),
        }
        let input = SenseInput { grid, footprints, draws };
        if let Ok(tables) = sensing.contiguous_iter_mut() {
            for (ids, states, radars, velodynes, omniscient, errors, mut readings) in tables {
                let table = SensingTable { ids, states, radars, velodynes, omniscient, errors };
                parallelism.for_each_chunk_at(&mut readings, scratch, |start, chunk, s| {
                    sense_chunk(input, table, start, chunk, s)
                });
            }
        } else {
            // Only if a component were stored sparsely (none is): one at a time.
            if scratch.is_empty() {
                scratch.push(SenseScratch::default());
            }
            for (id, state, radar, velodyne, omniscient, errors, mut readings) in sensing.iter_mut() {
                let table = SensingTable {
                    ids: std::slice::from_ref(id),
                    states: std::slice::from_ref(state),
                    radars: radar.map(std::slice::from_ref),
                    velodynes: velodyne.map(std::slice::from_ref),
                    omniscient,
                    errors: errors.map(std::slice::from_ref),
                };
                sense_chunk(input, table, 0, std::slice::from_mut(&mut *readings), &mut scratch[0]);
            }
        }
    }
}
