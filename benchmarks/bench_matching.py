"""Speed of automatic opti-acoustic matching: one rig pair (thesis scene, thesis water)."""

from __future__ import annotations

import numpy as np
from _timing import median_ms

TITLE = "Automatic opti-acoustic matching"
DESCRIPTION = ("`matching.match` on one simulated pair of `thesis_scene1` (BlueView P900-90 750 x 512 polar "
               "image, 600 x 400 camera, thesis water, default sonar noise), target <= 1 s per pair; against "
               "simulating that pair (`simulate_rig`: both sensors) and against its stages (CFAR sonar features, "
               "the arc search, the seabed-contact search, the face-plane model with and without every beam's crease, the point above the foot, the candidates' foot-edge evidence, the seabed point, the candidate trees; for the first design, corners and the epipolar gate); and the two-view "
               "matching with a second pair after a known motion.")


def run() -> list[dict]:
    from optiacoustic import scenes
    from optiacoustic.experiments.matching import _rig_for, simulate_pair
    from optiacoustic.matching import MatchOptions, detect_camera_features, detect_sonar_features, match
    from optiacoustic.matching.acoustic import elevation_maps, fit_seabed
    from optiacoustic.matching.arc_search import gradient_image, search_arcs
    from optiacoustic.matching.gating import mahalanobis_sq
    from optiacoustic.optical import Water
    from optiacoustic.simulation import simulate_rig

    scene = scenes.get("thesis_scene1")
    s, o, rig = simulate_pair(scene)
    spec = s.spec
    t_match = median_ms(lambda: match(s, o.image, rig), repeat=7, warmup=1)
    corners = MatchOptions(method="corners")
    t_corners = median_ms(lambda: match(s, o.image, rig, options=corners), repeat=5, warmup=1)
    _, sp = _rig_for(scene.view.eye, scene.view.target)
    water = Water.preset("thesis")
    t_sim = median_ms(lambda: simulate_rig(scene, rig, sp, water=water, seed=0), repeat=5, warmup=1)
    t_cam = median_ms(lambda: detect_camera_features(o.image), repeat=7, warmup=1)
    t_son = median_ms(lambda: detect_sonar_features(s.image, s.ranges, s.azimuths,
                                                    range_resolution=spec.range_resolution,
                                                    beamwidth=spec.beamwidth_azimuth), repeat=7, warmup=1)
    cf = detect_camera_features(o.image)
    sf = detect_sonar_features(s.image, s.ranges, s.azimuths, range_resolution=spec.range_resolution,
                               beamwidth=spec.beamwidth_azimuth)
    t_gate = median_ms(lambda: mahalanobis_sq(rig, cf.pixels, cf.sigma_pixel, sf.ranges, sf.azimuths,
                                              sf.sigma_range, sf.sigma_azimuth), repeat=7, warmup=1)
    plane = fit_seabed(s.image, s.ranges, s.azimuths, rig.fov_elevation)
    cells = np.zeros(s.image.shape, bool)
    cells[sf.bins, sf.beams] = True
    lo, hi, _ = elevation_maps(s.image, s.ranges, s.azimuths, plane, rig.fov_elevation, cells=cells)
    t_acou = median_ms(lambda: elevation_maps(s.image, s.ranges, s.azimuths, fit_seabed(
        s.image, s.ranges, s.azimuths, rig.fov_elevation), rig.fov_elevation, cells=cells), repeat=7, warmup=1)
    t_arc = median_ms(lambda: search_arcs(rig, sf.ranges, sf.azimuths, lo[sf.bins, sf.beams], hi[sf.bins, sf.beams],
                                          gradient_image(o.image)), repeat=7, warmup=1)
    from optiacoustic.matching.contact import search_contacts

    grad = gradient_image(o.image)
    t_contact = median_ms(lambda: search_contacts(rig, plane, sf.ranges, sf.azimuths, lo[sf.bins, sf.beams],
                                                  hi[sf.bins, sf.beams], grad), repeat=7, warmup=1)
    from optiacoustic.matching.contact import crease_positions, echo_start_ranges
    from optiacoustic.matching.face_plane import face_labels, face_planes

    ch = search_arcs(rig, sf.ranges, sf.azimuths, lo[sf.bins, sf.beams], hi[sf.bins, sf.beams], grad)
    r_on = np.minimum(echo_start_ranges(s.image, s.ranges, sf.bins, sf.beams), sf.ranges)

    from optiacoustic.matching.match import _beam_creases
    from optiacoustic.matching.sonar_features import cfar_map

    def plane_stage(beams=False):
        labels = face_labels(grad)
        uv = np.rint(np.nan_to_num(ch.pixels)).astype(int)
        face = np.where(ch.found, labels[np.clip(uv[:, 1], 0, labels.shape[0] - 1),
                                         np.clip(uv[:, 0], 0, labels.shape[1] - 1)], 0)
        C, ok = crease_positions(rig, ch.top_pixels, r_on)
        # (the CFAR maps are computed here, though match() shares them with the other stages)
        sonar = (s.image, s.ranges, s.azimuths, cfar_map(np.asarray(s.image, np.float64))) if beams else None
        extra = _beam_creases(rig, sonar, face, ok, sf.ranges, sf.azimuths, r_on,
                              labels) if beams and (ok & (face > 0)).any() else None
        return face_planes(rig, plane, sf.ranges, sf.azimuths, face, C, ok, np.nan_to_num(ch.elevations), labels,
                           extra=extra)

    t_plane = median_ms(plane_stage, repeat=7, warmup=1)
    t_plane_beams = median_ms(lambda: plane_stage(True), repeat=7, warmup=1)
    from optiacoustic.matching.contact import echo_end_ranges, foot_points

    t_foot = median_ms(lambda: foot_points(rig, plane, sf.ranges, sf.azimuths,
                                           echo_end_ranges(s.image, s.ranges, sf.bins, sf.beams)), repeat=7, warmup=1)
    m = match(s, o.image, rig, min_score=0.0)
    note = f"{len(sf)} sonar features, {len(m)} matches (arc search)"
    from optiacoustic.matching.contact import foot_edges

    m_r, m_th = m.ranges, m.azimuths
    m_el = [np.asarray(m.features[f"{k}_elevation"], float) for k in ("arc", "crease", "plane", "foot")]
    t_edges = median_ms(lambda: [foot_edges(rig, m.seabed, m_r, m_th, el, grad) for el in m_el], repeat=7, warmup=1)
    from optiacoustic.matching.acoustic import seabed_points

    t_seabed = median_ms(lambda: seabed_points(rig, m.seabed, m_r, m_th, rig.fov_elevation), repeat=7, warmup=1)
    from optiacoustic.matching import ranking

    avail = np.column_stack([np.isfinite(np.asarray(m.features[f"tree_p_{k}"], float)) for k in ranking.CANDIDATES])
    t_rank = median_ms(lambda: ranking.candidate_probabilities(m.features, avail), repeat=7, warmup=1)

    def load_trees():
        ranking._booster.cache_clear()
        ranking._booster(str(ranking.MODEL_FILE))

    t_load = median_ms(load_trees, repeat=5, warmup=1)
    no_trees = MatchOptions(rank_model=False)
    t_match_off = median_ms(lambda: match(s, o.image, rig, options=no_trees), repeat=7, warmup=1)
    from optiacoustic.experiments.matching import moved_view
    from optiacoustic.matching.optical_two_view import flow_field

    s2, o2, motion = moved_view(scene, dict(surge=0.5, sway=0.25, heave=0.0, yaw_deg=2.0))
    t_two = median_ms(lambda: match(s, o.image, rig, second=(s2, o2.image), motion=motion), repeat=5, warmup=1)
    t_flow = median_ms(lambda: flow_field(o.image, o2.image), repeat=7, warmup=1)
    return [
        dict(name="match one pair", value=t_match / 1e3, unit="s", reference="target 1 s", ratio=t_match / 1e3,
             note=note),
        dict(name="match with a second pair (two views, known motion)", value=t_two / 1e3, unit="s",
             reference="target 1 s per pair (2 pairs here)", ratio=t_two / 1e3 / 2,
             note="view 1 + view 2 matched, optical flow both ways, flow and correlation sweeps"),
        dict(name="optical flow between the two camera images (DIS)", value=t_flow, unit="ms",
             reference="match one pair", ratio=t_flow / t_match, note="600 x 400"),
        dict(name="match one pair, first design (corners)", value=t_corners / 1e3, unit="s", reference="target 1 s",
             ratio=t_corners / 1e3, note=f"{len(sf)} sonar x {len(cf)} camera features"),
        dict(name="seabed plane + elevation intervals", value=t_acou, unit="ms", reference="match",
             ratio=t_acou / t_match, note="at the sonar features' cells"),
        dict(name="arc search (gradient image + all arcs)", value=t_arc, unit="ms", reference="match",
             ratio=t_arc / t_match, note="400 elevation samples per arc"),
        dict(name="seabed-contact (foot) search, all arcs", value=t_contact, unit="ms", reference="match",
             ratio=t_contact / t_match, note="400 elevations x 16 segment samples per arc"),
        dict(name="face-plane model (face labels + plane fits + arc-plane points), all arcs", value=t_plane,
             unit="ms", reference="match", ratio=t_plane / t_match,
             note="connected components of edge-free pixels; a RANSAC over crease pairs per face window"),
        dict(name="face-plane model fitted to every beam's crease (the default), all arcs", value=t_plane_beams,
             unit="ms", reference="face-plane model (the features' creases alone)", ratio=t_plane_beams / t_plane,
             note="one more CFAR map, echo starts of every beam a face spans, one arc per start"),
        dict(name="point above the foot (echo end + seabed plane), all features", value=t_foot, unit="ms",
             reference="match", ratio=t_foot / t_match, note="closed form per feature; one CFAR map"),
        dict(name="foot-edge evidence of every candidate (round i15j), all matches", value=t_edges, unit="ms",
             reference="match", ratio=t_edges / t_match,
             note="4 candidates x (5 x 5 dilation + 16 segment samples)"),
        dict(name="seabed point (round i15k), all matches", value=t_seabed, unit="ms", reference="match",
             ratio=t_seabed / t_match, note="closed form per match: the arc meets the sonar's seabed plane"),
        dict(name="candidate trees (rounds i15v-i15x), every offered candidate", value=t_rank, unit="ms",
             reference="match", ratio=t_rank / t_match,
             note=f"LightGBM, {ranking.RANK_ROUNDS} trees of {ranking.RANK_PARAMS['num_leaves']} leaves, {int(avail.sum())} rows "
                                         f"({len(m)} matches) x {len(ranking.RANK_FEATURES)} inputs, one thread"),
        dict(name="loading the candidate trees (once per process)", value=t_load, unit="ms", reference="match",
             ratio=t_load / t_match, note="gzip + LightGBM's text model parser"),
        dict(name="match one pair with the trees off (rank_model=False)", value=t_match_off / 1e3, unit="s",
             reference="match one pair (trees on)", ratio=t_match_off / t_match,
             note="the candidate models choose and score"),
        dict(name="match / simulate the pair", value=t_match, unit="ms", reference="simulate_rig (both sensors)",
             ratio=t_match / t_sim, note=f"simulate_rig {t_sim:.0f} ms"),
        dict(name="camera corners (OpenCV)", value=t_cam, unit="ms", reference="match (arc search)",
             ratio=t_cam / t_match,
             note="CLAHE + goodFeaturesToTrack + cornerSubPix"),
        dict(name="sonar CFAR features", value=t_son, unit="ms", reference="match", ratio=t_son / t_match,
             note="peaks and onsets"),
        dict(name="epipolar gate (all pairs)", value=t_gate, unit="ms", reference="match (arc search)",
             ratio=t_gate / t_match,
             note=f"{len(sf) * len(cf)} pairs"),
    ]
