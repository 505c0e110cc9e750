"""Shared test fixtures: the scene bundles the tests run on (../shared's third-party scenes when present, else
the project's own stand-ins, see tests/project_scenes.py), and where the third-party scenes live; and the test
tiers: the tests listed in :data:`FULL_TIER_ONLY` carry the ``slow`` marker, so ``bash scripts/test.sh --quick``
(pytest ``-m "not slow"``) leaves them to the full run (``bash scripts/test.sh``, CI)."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import pytest

from tests.project_scenes import SHARED_SCENES, SceneBundles, shared_available

__all__ = ["SHARED_SCENES", "FULL_TIER_ONLY", "FULL_TIER_ONLY_MODULES"]

# The quick tier (bash scripts/test.sh --quick) is the suite without these: the tests over 1 s in either of
# two runs on 2 shared cores (load 2-5; everything else, 1460 s in all, then without the tests over 2 s, since
# a module's fixture moves to the next test that uses it). The quick tier keeps cheaper tests of each package
# (optics, trace, plan, encode, evaluate, service, agent), the service's end-to-end jobs (tests/service/
# test_e2e.py) and one end-to-end render (tests/cli/test_cli_render.py); 3 min on 2 shared cores. Test file ->
# test names (a name without [params]: every case).
FULL_TIER_ONLY: dict[str, list[str]] = {
    "tests/agent/test_agent_e2e.py": [
        "test_agent_cli_refuses_bad_settings", "test_agent_follows_the_service_and_recovers",
    ],
    "tests/agent/test_capture.py": [
        "test_capture_cli_refuses_bad_input",
        "test_capture_moves_in_order_waits_for_settled_then_plays_and_triggers",
        "test_capture_survives_the_serial_line_vanishing",
    ],
    "tests/agent/test_daemon_policies.py": [
        "test_policy_capture_runs_the_sequence_for_a_new_stack",
    ],
    "tests/agent/test_focus.py": [
        "test_line_vanishes_and_comes_back", "test_tcp_reset_on_open_move_ack_then_settled",
        "test_timeouts_and_unreachable",
    ],
    "tests/evaluate/test_viewer_score.py": [
        "test_one_scale_sees_brightness_that_steps_with_the_eye",
        "test_one_share_for_every_colour_sees_a_red_cast_through_large_pupils",
    ],
    "tests/service/test_evaluation_job.py": [
        "test_an_evaluated_job_scores_every_depth_of_its_sweep",
        "test_the_scores_of_a_depth_are_those_of_its_pictures",
        "test_a_job_without_an_evaluation_answers_404_and_the_files_are_checked",
        "test_the_estimate_counts_the_evaluation",
    ],
    "tests/service/test_e2e.py": [
        "test_a_time_limited_job_renders_until_its_limit", "test_events_show_progress_then_the_final_state",
        "test_holo_submit_cli_uploads_follows_and_downloads", "test_upload_reports_the_bundle_and_plan_fills_in",
    ],
    "tests/service/test_hostile.py": [
        "test_a_job_too_big_for_the_workers_is_refused_at_submit", "test_hostile_jobs_are_refused",
        "test_hostile_uploads_are_refused_and_nothing_is_stored",
        "test_plan_errors_name_the_users_file_not_the_server", "test_slow_and_idle_connections_are_closed",
        "test_stored_artifacts_are_checked_before_serving_or_reuse", "test_token_expiry_rate_limit_and_metrics",
        "test_uploaded_code_never_runs_and_no_outside_byte_leaks",
    ],
    "tests/service/test_hostile_bundles.py": [
        "test_hostile_bundles_get_one_line_4xx_and_the_server_keeps_serving",
        "test_no_job_on_a_scene_whose_plan_failed", "test_substitution_and_includes_cannot_blow_the_xml_up",
    ],
    "tests/service/test_hostile_service.py": [
        "test_a_body_trickled_at_one_byte_a_second_times_out",
        "test_an_unauthenticated_body_is_refused_before_it_is_read",
        "test_the_stack_names_its_scene_relative_to_the_bundle",
        "test_unsandboxed_server_keeps_its_files_private_and_says_so",
    ],
    "tests/service/test_robustness.py": [
        "test_a_job_that_keeps_dying_fails_with_a_reason", "test_cancel_running_and_queued_jobs",
        "test_kill_9_of_a_worker_requeues_until_it_succeeds",
        "test_server_killed_then_stopped_mid_queue_loses_nothing",
    ],
    "tests/service/test_sandbox.py": [
        "test_a_job_that_lies_about_its_stack_hash_fails",
        "test_a_job_that_swaps_its_files_for_fifos_and_links_leaves_the_scheduler_running",
        "test_an_artifact_swapped_for_a_link_to_the_database_is_dropped",
        "test_job_runs_as_its_slot_uid_and_its_dir_is_taken_back", "test_plan_runs_as_the_planner_uid",
        "test_sandbox_on_refuses_to_start_when_not_possible",
        "test_sandbox_users_cannot_read_the_database_the_lock_or_jobs",
    ],
    "tests/service/test_units.py": [
        "test_second_server_on_the_same_data_dir_is_refused", "test_serve_and_token_cli_errors",
    ],
    "tests/baselines/test_baseline_defaults.py": [
        "test_every_baseline_runs_with_its_defaults_on_each_project_scene[cbox]",
        "test_every_baseline_runs_with_its_defaults_on_each_project_scene[demo]",
        "test_every_baseline_runs_with_its_defaults_on_each_project_scene[paper-glass]",
        "test_every_baseline_runs_with_its_defaults_on_each_project_scene[paper-glossy]",
        "test_every_baseline_runs_with_its_defaults_on_each_project_scene[paper-mirror]",
        "test_every_baseline_runs_with_its_defaults_on_each_project_scene[veach-bidir]",
        "test_every_baseline_runs_with_its_defaults_on_each_project_scene[veach-mis]",
        "test_every_baseline_runs_with_its_defaults_on_the_shared_bundles",
    ],
    "tests/baselines/test_baseline_focal_stack.py": [
        "test_a_time_limit_stops_each_colour_early_and_otherwise_changes_nothing",
        "test_cli_writes_result_and_stack", "test_each_plane_is_sharp_at_its_own_focus_and_the_loss_falls",
        "test_render_focal_stack_puts_its_planes_at_the_cards",
        "test_the_result_and_its_stack_load_in_view_and_evaluate",
    ],
    "tests/baselines/test_baseline_light_field.py": [
        "test_a_black_scene_and_an_emitter_seen_edge_on_stay_finite",
        "test_cli_light_field_writes_a_result_and_rejects_bad_input",
        "test_parallax_is_right_and_the_card_off_the_rs_plane_never_focuses",
        "test_the_fit_reads_a_stereogram_back_and_fits_phase_only_frames_to_a_light_field",
    ],
    "tests/scene/test_bundle_semantics.py": [
        "test_preloaded_plugins_never_resolve_through_a_scene_folder",
        "test_traced_loads_never_open_a_file_outside_their_bundle",
    ],
    "tests/cli/test_cli_render.py": [
        "test_bad_options_are_refused_clearly[args5---time-limit-s]",
        "test_bad_options_are_refused_clearly[args6---time-limit-s]", "test_plan_json",
    ],
    "tests/bench/test_device_check.py": [
        "test_device_check_dry_run",
    ],
    "tests/display/test_display.py": [
        "test_plan_of_a_wide_camera_uses_the_displays_f_and_says_the_view_differs",
        "test_plan_options_override_a_profile_file",
    ],
    "tests/encode/test_encoding.py": [
        "test_blocks_of_frames_give_the_unchunked_stack", "test_complex_scale_of_the_target_only_shifts_the_phase",
        "test_heap_reuse_changes_no_number", "test_sgd_looks_better_than_naive_to_a_viewer",
        "test_sgd_on_a_traced_scene", "test_sgd_reaches_its_error_on_a_random_phase_target_and_beats_naive",
        "test_stop_rule_in_decibels", "test_streamed_file_encoding_equals_the_in_memory_one",
        "test_without_a_fourier_filter_the_light_outside_the_cone_counts",
    ],
    "tests/plan/test_estimate_probe.py": [
        "test_a_real_probe_measures_positive_costs",
    ],
    # a job submitted from the page's form and watched to its end (25 s): test_re_run_with_changes submits from
    # the form, the done job's tests show a finished job's page and list, test_web_journey.py follows progress
    "tests/service/test_web_page.py": [
        "test_a_job_named_after_its_file_whose_progress_only_moves_forward",
    ],
    # a demo scene planned by a server for one quality target over the API: the quick tier keeps the quality
    # model's own tests in the module and test_web_page.py's form choosing options for a target on the server
    "tests/service/test_quality_estimate.py": [
        "test_a_quality_target_over_the_api",
    ],
    # `holo plan --probe` on the demo scene: the service's planner runs the same command in
    # test_the_services_estimate_uses_its_planners_probe, whose estimate takes the probe only when it is usable
    "tests/service/test_estimate_probe.py": [
        "test_holo_plan_probe_times_the_scene",
    ],
    "tests/evaluate/test_evaluation.py": [
        "test_a_phase_stack_is_lit_with_its_laser_powers",
        "test_a_view_offset_moves_the_reconstruction_like_the_ground_truth[offset0]",
        "test_a_view_offset_moves_the_reconstruction_like_the_ground_truth[offset1]",
        "test_cbox_frames_average_speckle_and_layers_keep_colour_balance",
        "test_ground_truth_puts_the_dot_where_x_equals_f_tan", "test_holo_evaluate_and_baseline_cli",
        "test_near_and_far_focus_like_the_ground_truth_and_layers_misplace_the_mirror_image",
        "test_reconstruction_lands_on_the_ground_truth_pixel", "test_render_estimate_cli",
        "test_the_estimate_counts_the_work_the_render_does",
    ],
    "tests/formats/test_formats_light.py": [
        "test_agent_and_formats_import_without_torch_mitsuba_drjit",
    ],
    "tests/bench/test_paper_report.py": [
        "test_frames_the_convergence_map_may_share", "test_reference_against_itself_and_cue_depth",
    ],
    "tests/scene/test_paper_scenes.py": [
        "test_demo_renders_a_paper_scene", "test_depth_scene_spans_the_paper_image_volume",
        "test_fast_preset_keeps_the_glossy_highlight",
        "test_glass_ball_images_the_card_at_the_paraxial_thick_lens_position",
        "test_glossy_highlight_moves_with_the_view",
        "test_mirror_image_lies_at_the_apparent_depth_of_the_reflected_object",
        "test_small_render_is_finite_and_lit", "test_the_camera_sees_the_paper_display_view",
    ],
    "tests/optics/test_propagation.py": [
        "test_asm_matches_rayleigh_sommerfeld[shape0-1e-06-5e-07-4e-06-0.0001-0.0-0.0]",
        "test_asm_matches_rayleigh_sommerfeld[shape1-2e-07-4.55e-07-7e-07-5e-06-0.0-0.0]",
        "test_inverse_fft_is_right_at_padded_production_sizes", "test_long_distance_phase_precision_complex64",
        "test_production_sizes_against_analytic_and_complex128",
        "test_sqrt_is_accurate_and_the_same_in_every_fresh_process",
    ],
    "tests/test_render_memory.py": [
        "test_chunked_views_equal_the_unchunked_ones", "test_streamed_chunked_render_equals_the_unchunked_one",
        "test_the_phase_bank_is_freed_before_the_slm_propagation",
    ],
    "tests/plan/test_time_limit.py": [
        "test_holo_render_with_a_time_limit", "test_the_passes_make_the_spp_weighted_mean",
    ],
    "tests/cli/test_view_cli.py": [
        "test_encode_writes_a_numpy_readable_stack",
        "test_service_preview_is_what_holo_view_writes_and_a_failed_preview_keeps_the_pictures",
        "test_view_focuses_on_the_right_point[result]",
    ],
    "tests/optics/test_viewing.py": [
        "test_defocus_blur_grows_with_pupil_as_geometry_predicts",
        "test_frame_averaging_reduces_speckle_like_inverse_sqrt_frames", "test_point_source_focuses_at_its_depth",
    ],
    "tests/optics/test_cone_equaliser.py": [
        "test_a_white_card_keeps_its_colour_in_every_view", "test_a_white_card_looks_white_through_the_report_pupil",
        "test_few_rays_do_not_tint_the_views",
    ],
    "tests/trace/test_directional_frames.py": [
        "test_a_glowing_plate_has_far_less_speckle_with_directional_frames",
        "test_a_tilted_plate_is_as_bright_from_the_left_as_from_the_right",
        "test_a_white_plate_stays_white_in_every_view", "test_every_beam_carries_its_share_at_every_wrp_margin",
    ],
    "tests/trace/test_emitters.py": [
        "test_a_textured_area_light_in_view_is_imaged",
        "test_every_emitter_kind_lights_the_hologram_like_mitsubas_render",
        "test_field_amplitude_goes_as_the_square_root_of_the_emitted_power",
    ],
    "tests/trace/test_eyebox.py": [
        "test_every_colour_leaves_within_the_common_cone",
    ],
    "tests/trace/test_focus.py": [
        "test_equal_radiance_at_two_depths_is_equally_bright", "test_plane_focuses_at_predicted_depth",
        "test_twice_the_radiance_gives_twice_the_intensity", "test_two_planes_focus_at_their_own_depths",
    ],
    "tests/trace/test_hard_cases.py": [
        "test_camera_inside_glass", "test_point_like_emitter_between_the_prepass_rays_keeps_the_wrp_in_front",
        "test_rays_escape_and_emitter_seen_directly", "test_scene_that_cannot_fit_is_refused",
        "test_sub_wavelength_pitch_hemisphere", "test_surface_close_to_the_wrp_margin",
        "test_total_internal_reflection_in_glass_block", "test_two_facing_mirrors_hit_the_cap",
    ],
    "tests/trace/test_mirror_glass.py": [
        "test_convex_mirror_sphere_obeys_the_mirror_equation", "test_flat_mirror_focuses_at_the_virtual_image",
        "test_glass_slab_brings_the_image_closer", "test_rays_through_a_glass_ball_add_up_coherently",
    ],
    "tests/trace/test_path_reuse.py": [
        "test_frames_have_equal_mean_intensity",
    ],
    "tests/plan/test_plan.py": [
        "test_veach_mis_plan_has_no_coherent_loop",
        "test_cbox_plan_has_mirror_and_glass", "test_diffuse_scene_planned_equals_forced_and_traces_less",
        "test_veach_bidir_plan_is_glossy_with_glass",
    ],
    "tests/trace/test_sphere_pole.py": [
        "test_fused_kernel_images_the_axis_ray_at_the_ball_lens_focus[poles-on-the-axis]",
        "test_reference_chain_images_the_axis_ray_at_the_ball_lens_focus[poles-on-the-axis]",
    ],
    "tests/trace/test_tilted_surface.py": [
        "test_a_tilted_white_plate_has_the_colour_and_brightness_of_a_facing_one_in_every_view",
    ],
    "tests/trace/test_wrp_planes.py": [
        "test_two_planes_estimate_the_same_field_with_far_less_noise",
    ],
}
# Whole modules, and a new test that takes long: list it here or mark it @pytest.mark.slow in its file.
FULL_TIER_ONLY_MODULES: dict[str, str] = {
    "tests/scene/test_plugin_sweep.py::test_every_admitted_plugin_renders_or_is_refused_clearly":
        "one render per admitted plugin; tests/trace/test_emitters.py and test_hard_cases.py render the kinds",
    "tests/service/test_ray.py": "a Ray cluster per test; tests/service/test_units.py covers the engine choice",
    "tests/service/test_ray_connect.py": "Ray Client start-up",
    "tests/service/test_web.py": "headless Chromium; tests/service/test_units.py covers the page's API",
    "tests/service/test_web_compare.py": "headless Chromium on two jobs; tests/service/test_web_page.py drives the page",
    "tests/service/test_web_journey.py": "headless Chromium through three jobs of the mirror room; "
                                         "tests/service/test_web_page.py drives each part",
    "tests/service/test_web_evaluation.py": "headless Chromium on an evaluated job; "
                                            "tests/service/test_evaluation_job.py holds the API it shows",
    "tests/service/test_web_list.py": "headless Chromium on four jobs; tests/service/test_scene_picture.py and "
                                      "test_queue_status.py hold the API it shows",
    "tests/service/test_schemathesis.py": "API fuzzing; test_hostile*.py send bad input by hand",
    "tests/service/test_send_display.py": "two finished jobs and a display agent; tests/service/test_web_phase.py "
                                          "sends a job to a display in the quick tier",
    "tests/trace/test_wavekernel.py": "millions of rays against the reference chain; tests/trace/test_sphere_pole.py "
                                       "runs both on few rays",
}


@pytest.fixture(scope="session")
def shared_scenes() -> Path:
    """../shared/scenes, or a skip that says clearly that it is missing. Only for tests that need third-party
    data as such; every other test takes :func:`scene_bundle` / :func:`scene_bundles`, which never skip."""
    if not shared_available():
        pytest.skip(f"shared scenes not found at {SHARED_SCENES} (clone the project beside ../shared), or "
                    "hidden by HOLO_NO_SHARED")
    return SHARED_SCENES


@pytest.fixture(scope="session")
def project_scene_bundles(tmp_path_factory: pytest.TempPathFactory) -> SceneBundles:
    """The project's own scene bundles, written once per session on first use."""
    return SceneBundles("project", tmp_path_factory.mktemp("project-scenes"))


@pytest.fixture(scope="session")
def scene_bundles(project_scene_bundles: SceneBundles) -> SceneBundles:
    """The shared bundles when ../shared is there (and HOLO_NO_SHARED unset), else the project's stand-ins."""
    return SceneBundles("shared", SHARED_SCENES) if shared_available() else project_scene_bundles


@pytest.fixture(scope="session")
def scene_bundle(scene_bundles: SceneBundles) -> Callable[[str], Path]:
    """``scene_bundle("cbox-mirror-glass")``: that bundle's folder, shared if present, else the project's."""
    return scene_bundles.folder


@pytest.fixture(scope="session")
def bundles_by_source(project_scene_bundles: SceneBundles) -> dict[str, SceneBundles]:
    """Every available source by name (tests.project_scenes.SCENE_SOURCES): ``project`` always, ``shared``
    when present. For cheap tests that run on both."""
    out = {"project": project_scene_bundles}
    if shared_available():
        out["shared"] = SceneBundles("shared", SHARED_SCENES)
    return out


@pytest.hookimpl(tryfirst=True)  # before pytest's own -m selection reads the markers
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The tests of :data:`FULL_TIER_ONLY` and :data:`FULL_TIER_ONLY_MODULES` get the ``slow`` marker."""
    for item in items:
        path, _, name = item.nodeid.partition("::")
        names = FULL_TIER_ONLY.get(path, ())
        if (name in names or name.split("[")[0] in names
                or any(item.nodeid == p or item.nodeid.startswith(p if "::" in p else p + "::")
                       for p in FULL_TIER_ONLY_MODULES)):
            item.add_marker(pytest.mark.slow)
