"""The results page's sections (docs/gen_results.py): for each results JSON's stem, its title, what it
measures and the command that reproduces it. Only the standard library, as gen_results."""

from __future__ import annotations

#: stem -> (title, what it measures, command that reproduces it). Order of the page.
SECTIONS: dict[str, tuple[str, str, str]] = {
    "backprojection": ("Backprojection kernel",
                       "Throughput of the time-domain backprojection kernel per interpolation mode and oversampling, "
                       "against its signal-to-error ratio to the exact matched filter; the numpy reference; torchbp "
                       "where installed.",
                       ".venv/bin/python benchmarks/backprojection.py"),
    "kernel_versions": ("Backprojection kernel against its previous version",
                        "The kernel against the one before issue 34 (each in a worker process of its own), timed "
                        "alternately in one run: speed-up on 1 and 2 threads, cycles per backprojection, SER of both.",
                        ".venv/bin/python benchmarks/kernel_versions.py"),
    "kernel_midpoint": ("Backprojection kernel: the one-antenna midpoint form",
                        "The kernel that ranges a one-antenna pass by one series on the TX-RX midpoint against the "
                        "one before it (two series a pixel), each in a worker process of its own, alternating in one "
                        "run: speed-up on 1 and 2 threads, cycles per backprojection, SER of both; on a loaded machine "
                        "(the load is in the JSON).",
                        ".venv/bin/python benchmarks/kernel_versions.py --baseline fe81155 --cases one_antenna "
                        "benchmark --name kernel_midpoint"),
    "kernel_hoist": ("Backprojection kernel: the per-(block, profile) table",
                     "The kernel that computes each block's per-profile scalars for 64 profiles at once, vectorised "
                     "over them (imaging/block_profiles.py), against the one that computed them in its profile loop, "
                     "each in a worker process of its own, alternating in one run: speed-up on 1 and 2 threads, "
                     "cycles per backprojection, SER of both; on a loaded machine (the load is in the JSON).",
                     ".venv/bin/python benchmarks/kernel_versions.py --baseline f671da8 --rounds 4 --name kernel_hoist"),
    "kernel_permute": ("Backprojection kernel: the gather as vector permutes",
                       "The kernel that takes the bins of 16 pixels (4 x 4) out of a 16-bin window by AVX-512 "
                       "permutes (imaging/bin_gather.py), against the one with the scalar gather (ff18b4a), each in a "
                       "worker process of its own, alternating in one run: speed-up on 1 and 2 threads, cycles per "
                       "backprojection, SER of both; on a loaded machine (the load is in the JSON).",
                       ".venv/bin/python benchmarks/kernel_versions.py --baseline ff18b4a --name kernel_permute"),
    "kernel_placement": ("Backprojection kernel: each pixel's bin placed for one mode (tried, reverted)",
                         "The kernel whose per-pixel placement loops were compiled for the linear mode alone "
                         "(b91f47f: they computed the nearest mode's bin too and stored one under a mask), against "
                         "ac0c048, each in a worker process of its own, alternating in one run: speed-up on 1 and 2 "
                         "threads, cycles per backprojection, SER of both. Measured on the quiet machine with "
                         "b91f47f's kernel checked out (0.90x: reverted, e40edd3); the load is in the JSON.",
                         "git checkout b91f47f -- imaging/backprojection.py && .venv/bin/python "
                         "benchmarks/kernel_versions.py --baseline ac0c048 --rounds 4 --name kernel_placement; "
                         "git checkout HEAD -- imaging/backprojection.py"),
    "kernel_placement_fast_hour": ("Backprojection kernel: each pixel's bin placed for one mode, re-run in the VM's fast hour",
                                   "The same comparison as kernel_placement (b91f47f's kernel against ac0c048's, alternating "
                                   "in one run), an hour later, when the VM ran sarbot's kernels at full speed again "
                                   "(docs/benchmark-notes.md, the peer benchmark): 1.03-1.08x, where the slow hour gave 0.90x.",
                                   "git checkout b91f47f -- imaging/backprojection.py && .venv/bin/python "
                                   "benchmarks/kernel_versions.py --baseline ac0c048 --rounds 4 --name kernel_placement_fast_hour; "
                                   "git checkout HEAD -- imaging/backprojection.py"),
    "kernel_placement_avx2": ("Backprojection kernel: each pixel's bin placed for one mode, on a CPU without AVX-512 (kept)",
                              "b91f47f's per-mode placement loops re-applied on 6ecf8a6 (an AMD EPYC with AVX2: LLVM's masked "
                              "stores there are vmaskmovps, slow on AMD's cores), against 6ecf8a6, each in a worker process of "
                              "its own, alternating in one run: speed-up on 1 and 2 threads, cycles per backprojection, SER of both.",
                              ".venv/bin/python benchmarks/kernel_versions.py --baseline 6ecf8a6 --rounds 3 --name "
                              "kernel_placement_avx2"),
    "kernel_fused": ("Backprojection kernel: placement, gather and accumulation fused per 16-pixel group (tried, reverted)",
                     "The kernel that placed, gathered and accumulated each group of 16 pixels in one pass (7b03966) "
                     "against main's three passes over a block per profile (be1579c), each in a worker process of its "
                     "own, alternating in one run: speed-up on 1 and 2 threads, cycles per backprojection, SER of both. "
                     "Measured on an AMD EPYC without AVX-512 (the generic path: scalar pair gather), loaded machine "
                     "(the load is in the JSON); reverted. 7b03966's commit message says bit for bit: that held for an "
                     "earlier cut (the fusion on the AVX-512 path alone), not for 7b03966 (1.3e-6 of the peak).",
                     "git checkout 7b03966 -- imaging/backprojection.py && .venv/bin/python "
                     "benchmarks/kernel_versions.py --baseline be1579c --rounds 3 --name kernel_fused; "
                     "git checkout HEAD -- imaging/backprojection.py"),
    "kernel_avx2_gather": ("Backprojection kernel: the permute gather on AVX2 (AMD Zen 3)",
                           "The kernel with the AVX2 permute gather (8 pixels' bins out of an 8-bin window of two "
                           "256-bit registers: vpermps and a blend, imaging/bin_gather.py) against main's (dc9bbff: the "
                           "scalar pair gather on a CPU without AVX-512), each with its commit's whole imaging package in "
                           "a worker process of its own, alternating in one run: speed-up on 1 and 2 threads, cycles per "
                           "backprojection, SER of both. Measured on an AMD EPYC (Zen 3, AVX2, no AVX-512), loaded (the "
                           "load is in the JSON).",
                           ".venv/bin/python benchmarks/kernel_versions.py --baseline dc9bbff --whole-package --rounds 3 "
                           "--name kernel_avx2_gather"),
    "kernel_avx2_split_gather": ("Backprojection kernel: the AVX2 gather without blends (AMD Zen 3)",
                                 "The kernel whose AVX2 permute gather splits the window into real and imaginary "
                                 "registers once and permutes each planar row out of one of them (no blends; "
                                 "imaging/bin_gather.py) against main's (0e7a3c5), whole imaging packages, quick cases, "
                                 "alternating in one run, loaded (the load is in the JSON).",
                                 ".venv/bin/python benchmarks/kernel_versions.py --quick --whole-package --baseline "
                                 "0e7a3c5 --rounds 6 --name kernel_avx2_split_gather"),
    "kernel_avx2_split_gather_full": ("Backprojection kernel: the AVX2 gather without blends, full benchmark case",
                                      "The same comparison as kernel_avx2_split_gather on the full benchmark case (16 "
                                      "frames, 16 channels, 256 x 256 pixels), 3 rounds, loaded (the load is in the JSON).",
                                      ".venv/bin/python benchmarks/kernel_versions.py --whole-package --baseline 0e7a3c5 "
                                      "--rounds 3 --cases benchmark --name kernel_avx2_split_gather_full"),
    "gather_avx2_split": ("The AVX2 permute gather alone, without blends (AMD Zen 3)",
                          "gather_planar of the current imaging/bin_gather.py against 0e7a3c5's, each in a numba loop "
                          "over the same bins (16 x 16 blocks in 4 x 4 squares, bins spanning up to 7 per square), "
                          "alternating on one thread, thread CPU time; loaded (the load is in the JSON).",
                          ".venv/bin/python benchmarks/gather_versions.py --baseline 0e7a3c5 --rounds 15 "
                          "--name gather_avx2_split"),
    "kernel_avx2_no_masked_stores": ("Backprojection kernel: no masked stores left (AVX2, AMD Zen 3)", "fce53eb's kernel "
                                     "(no masked stores) against 4da3eec's, whole imaging packages, alternating in one "
                                     "run, loaded (the load is in the JSON).", ".venv/bin/python benchmarks/kernel_versions.py "
                                     "--baseline 4da3eec --whole-package --rounds 3 --name kernel_avx2_no_masked_stores"),
    "kernel_parts_avx2_quick": ("Backprojection kernel: cycles per part on AVX2 (AMD Zen 3), quick cases", "kernel_parts "
                                "of fce53eb's kernel on the AMD EPYC (AVX2, no AVX-512), quick cases, load 1.1-1.5.",
                                ".venv/bin/python benchmarks/kernel_parts.py --quick --name kernel_parts_avx2_quick"),
    "kernel_parts": ("Backprojection kernel: cycles per part",
                     "The kernel beside copies of itself that each leave one part out (the per-(block, profile) "
                     "table, each pixel's offset, bin and phase, the gather, the sine and cosine, the whole "
                     "interpolation and accumulation), alternating in one process on one thread: each part's cycles "
                     "per backprojection by difference; on a loaded machine (the load is in the JSON).",
                     ".venv/bin/python benchmarks/kernel_parts.py"),
    "machine_speed": ("The VM's speed over a few minutes",
                      "benchmarks/machine_speed.py's fixed probe repeated: sarbot's float32 kernel on 256 profiles x "
                      "128 x 128 points (1 thread), a float64 FMA loop and a 64 MiB copy, each the best of 5 repeats, "
                      "with the load and the host's steal time; the chart shows each relative to its best probe. Every "
                      "speed benchmark records one probe before and one after its run (provenance.machine_speed).",
                      ".venv/bin/python benchmarks/machine_speed.py --watch 240 --every 5"),
    "machine_speed_back_to_back": ("The probe's spread back to back",
                                   "benchmarks/machine_speed.py's probe repeated back to back for a minute: how far "
                                   "apart two probes of the same minute read (on the load the JSON records).",
                                   ".venv/bin/python benchmarks/machine_speed.py --watch 60 --every 0 --name "
                                   "machine_speed_back_to_back"),
    "block_sizes": ("Backprojection kernel: blocks of 512 and 1,024 points (tried, not taken)",
                    "The kernel with blocks of 256 (16 x 16), 512 (32 x 16, 16 x 32) and 1,024 (32 x 32) points, "
                    "alternating in one process, CPU time on 1 and 2 threads, SER of each; and per shape the share of "
                    "(block, profile) pairs per range-offset form, with the series' tolerance as it is and at the "
                    "midpoint form's (-100 dB). Measured on a loaded machine without AVX-512 (in the JSON).",
                    ".venv/bin/python benchmarks/block_sizes.py --rounds 3"),
    "block_sizes_tolerance_6nm": ("Backprojection kernel: larger blocks with the series' tolerance at 6 nm",
                                  "The same as the previous section with the kernel compiled with SERIES_TOLERANCE_M "
                                  "= 6e-9 m (1e-5 rad at 77 GHz, the midpoint form's budget) instead of 1e-9 m.",
                                  ".venv/bin/python benchmarks/block_sizes.py --rounds 3 --series-tolerance 6e-9 "
                                  "--name block_sizes_tolerance_6nm"),
    "peers": ("sarbot beside torchbp",
              "sarbot's kernel against the real torchbp (built from ../shared/bench/) in one process, alternating: its "
              "Cartesian and polar CPU kernels, two cases, each image's SER against the exact matched filter, 5 km out.",
              "python3 dev.py bench --peers"),
    "peers_one_antenna": ("sarbot beside torchbp: the one-antenna pass alone",
                          "The peers benchmark's one-antenna case on its own (no FFBP, not 5 km out): a quick look "
                          "after a kernel change, on whatever load the JSON records; the issue's figure is peers.json.",
                          "python3 dev.py bench --peers --cases one_antenna"),
    "image_command": ("`sarbot image` as a whole command",
                      "The command as a new process against its kernel alone, with the time of every stage.",
                      ".venv/bin/python benchmarks/image_command.py"),
    "image_command_quick": ("`sarbot image` as a whole command (quick)",
                            "The command benchmark's smoke run (cases of 4 and 8 frames, small grids), with its new "
                            "parts: the command's own stage times and 8 images in one process; on whatever load the "
                            "JSON records (11-13 on 2 cores when committed: its fractions are the load's).",
                            ".venv/bin/python benchmarks/image_command.py --quick --no-baseline"),
    "image_floor": ("How close any new process can get to the kernel",
                    "New processes that each do strictly less than `sarbot image` and no backprojection (the interpreter; "
                    "numpy; h5py and the frames read; their range compression as form_image does it; numba's kernel "
                    "loaded), the command and the kernel alone, interleaved: the bound on the command's fraction of "
                    "the kernel for any backprojector that range-compresses in its own process, and the kernel time "
                    "at which 85 % becomes possible; on whatever load the JSON records.",
                    ".venv/bin/python benchmarks/image_floor.py"),
    "command_end": ("How a `sarbot image` process ends",
                    "The command ended at once after its files are closed (exit handlers, streams flushed, os._exit) "
                    "against the interpreter's usual teardown, alternating, each a new process on the benchmark case: "
                    "the process's time outside the command's own stages, its wall and CPU time, the images compared.",
                    ".venv/bin/python benchmarks/command_end.py"),
    "range_window": ("Range compression of the bins an image needs",
                     "Only the range bins between the grid's nearest and farthest pixel (a chirp-z transform) against "
                     "every bin (the zero-padded FFT), alternated on the command's blocks: the window, the CPU time, "
                     "the images against each other and against the exact matched filter; one chirp's cost by window.",
                     ".venv/bin/python benchmarks/range_window.py"),
    "ffbp": ("Fast factorized backprojection",
             "FFBP against the direct kernel on the same profiles: speed-up against error energy and aperture; "
             "the settings' speed against their error; the default's error further out and longer.",
             ".venv/bin/python benchmarks/ffbp.py"),
    "ffbp_leaves": ("FFBP's leaf kernel, part by part",
                    "The leaf kernel on one thread, nanoseconds a backprojection: as it runs, without prefetching, "
                    "its geometry and its gather alone, with the rows in cache, against the direct kernel.",
                    ".venv/bin/python benchmarks/ffbp_leaves.py"),
    "ffbp_leaves_permute": ("FFBP's leaves with the permute gather",
                            "The leaf kernel compiled with the permute gather (imaging/bin_gather.py) and with the "
                            "scalar gather, alternated in one run: 16 leaves on one thread and FFBP's whole run on 2 "
                            "threads, in wall and CPU time; the groups of 16 the permutes took; the images compared.",
                            ".venv/bin/python benchmarks/ffbp_leaves_permute.py"),
    "ffbp_plan": ("FFBP's plan against the node-at-a-time plan",
                  "The 2 m aperture's plan (plan_factorized) against the builder it replaced (tests/reference_ffbp_plan.py), "
                  "alternated in one process, and FFBP with its plan against the direct kernel in each round, on 2 threads, "
                  "on whatever load the JSON records; each plan's page faults and system time, and the plan in fresh "
                  "processes (fresh_process: as sarbot image meets it); plan_conditions: a plan right after the direct "
                  "kernel, again, after a pause and on a new thread, each with its parts' CPU time and what ran beside it.",
                  ".venv/bin/python benchmarks/ffbp.py --plan"),
    "ffbp_plan_versions": ("FFBP's plan against the batched planner before it",
                           "The 2 m aperture's plan (plan_factorized: the tree in arrays, every node's frame in one pass, "
                           "the grids' edges a numba pass) against the batched planner it replaced "
                           "(tests/reference_ffbp_plan_batched.py), the plans equal to the bit: alternated in one process "
                           "(wall and CPU time, the median of the rounds' ratios), and in fresh processes (the first plan "
                           "and later ones; new_prepared: after sarbot image's start-up preparation), on whatever load "
                           "the JSON records.",
                           ".venv/bin/python benchmarks/ffbp_plan_versions.py"),
    "stripmap": ("Live strip map",
                 "The streaming strip map: frames per second against the sensor rate, and map error against an "
                 "offline full-resolution map, per setting.",
                 ".venv/bin/python benchmarks/stripmap.py"),
    "stripmap_ffbp": ("Live strip map with long apertures",
                      "The direct kernel against FFBP blocks in the live map: speed and the reflector's width.",
                      ".venv/bin/python benchmarks/stripmap_ffbp.py"),
    "stripmap_polar": ("Live strip map: work per frame, direct against each frame's beams",
                       "The live map's work per frame stage by stage, the direct kernel against the polar path "
                       "(each frame through its beams), interleaved, and both maps against every frame at presum 1.",
                       ".venv/bin/python benchmarks/stripmap_polar.py"),
    "stripmap_capacity": ("The live map's capacity: CPU per frame, part by part",
                          "The strip-map worker's CPU per frame on the soak's four radars (the daemon's own worker in one "
                          "process, CPU time, each part timed apart: bus decode, pre-summing, antenna placement, beams, "
                          "pixels, footprints, publishing), the share of one core it needs at 1x, and the code before "
                          "this issue's cuts and before its last round against now, interleaved; what a refocusing "
                          "map costs apart.",
                          ".venv/bin/python benchmarks/stripmap_capacity.py"),
    "stripmap_presum": ("The live map's CPU per frame at the configured pre-summing, main against the checkout",
                        "The daemon's strip-map worker on the soak's four radars (stripmap_capacity's scene and messages), "
                        "a baseline commit's map modules (map.py, polar.py, loaded from git) against the checkout's, two "
                        "workers taking every message in turn in one process: the main thread's CPU per frame, the "
                        "ratio per round, and the largest difference between the two maps below the peak.",
                        ".venv/bin/python benchmarks/stripmap_presum.py --rounds 4"),
    "map_cpu_per_frame": ("The live map worker's CPU per frame, one radar and four, a baseline commit against the checkout",
                          "The daemon's strip-map worker on the soak's frames (stripmap_capacity's scene and messages), "
                          "the baseline's imaging/stripmap/polar.py and map.py (loaded from git) against the checkout's, "
                          "two workers taking every message in turn in one process: process and thread CPU beside wall "
                          "time per frame, the ratio per round, for one radar and for the four-radar mix; the maps bit "
                          "for bit or their SER; and the beams' range compression over only the bins their pixels need "
                          "(chirp-z) against the full FFT. The lead's run with nothing else running (the load is in "
                          "the JSON).",
                          ".venv/bin/python benchmarks/map_cpu_per_frame.py"),
    "stripmap_thinning": ("What the live map's catch-up costs",
                          "Pre-summing, RX sums and thinning: CPU saved against image error.",
                          ".venv/bin/python benchmarks/stripmap_thinning.py"),
    "autofocus": ("Autofocus",
                  "Time per autofocused image against the plain backprojection, and the image quality it buys.",
                  ".venv/bin/python benchmarks/autofocus.py"),
    "autofocus_per_profile": ("Autofocus pulse by pulse (Gotcha)",
                              "The real Gotcha pass with a 0.3 rad/pulse random walk and an 11 rad polynomial added: "
                              "each method's peak against the clean image and the pulse-to-pulse steps it leaves.",
                              ".venv/bin/python benchmarks/autofocus_per_profile.py"),
    "autofocus_decision": ("Autofocus decision: contrast gate against half-band consistency",
                           "Synthesised 77 GHz passes with a drift, a 6.1 Hz vibration and a 2 % scale error: a point "
                           "target's width against the true image's over image SNR, and clutter's correlation with the "
                           "true image, for the forced estimate, the 20 dB contrast gate and the consistency decision "
                           "(with its weak-point test); the consistency test's false-alarm rate on independent noise; "
                           "the weak point target over noise seeds and clutter over more seeds.",
                           ".venv/bin/python benchmarks/autofocus_decision.py"),
    "autofocus_taper": ("Autofocus under a Taylor taper: PGA against entropy",
                        "Point-target passes with errors unlike the paper's (cubic drift, heading, scale, a 6.1 Hz "
                        "vibration over 1.2 m; all together over 0.6 m) under a Taylor taper: peak side lobe, width "
                        "and peak against the clean image, per method.",
                        ".venv/bin/python benchmarks/autofocus_taper.py"),
    "autofocus_weak_point": ("Autofocus: the weak-point test's false alarms on clutter",
                             "The weak-point detection (the only way a clutter-only pass reaches a track-error fit) "
                             "seed by seed on synthesised 77 GHz clutter passes, error-free and with the decision "
                             "benchmark's error, and its detections of a 14 dB point with that error: the false-alarm "
                             "rate with its 95 % Clopper-Pearson upper bound and the clutter's effective number of "
                             "independent cells. `seeds_done` and `stopped` say how far a partial run got.",
                             ".venv/bin/python benchmarks/autofocus_weak_point.py"),
    "rio": ("Radar-inertial odometry",
            "Accuracy on long simulated drives (evaluated with evo), the filter's settings against speed, and a "
            "real ROS bag. Accuracy with the midpoint strapdown (issue 35); its speeds were taken on a machine loaded "
            "by others and are not comparable (quiet-machine speeds: rio.json at fae5f5c, docs/benchmark-notes.md).",
            ".venv/bin/python benchmarks/odometry.py"),
    "odometry_versions": ("Which change moved the odometry's figures",
                          "The odometry benchmark's accuracy figures (7- and 10-lap drives, one radar, the real bag's "
                          "loop end) with the filter of earlier commits on the same recordings: the standstill changes "
                          "(1b9f9b5, 7744ef7) moved them, the midpoint strapdown (a6d4858 against this checkout) did not.",
                          ".venv/bin/python benchmarks/odometry_versions.py"),
    "odometry_speed": ("What halved the odometry's speed, and the fix",
                       "The odometry's time on the one-lap hall drive (four radars, and one) with fae5f5c's filter "
                       "(rio.json's quiet 106-116x), main before the fix (ac0c048) and this checkout, interleaved in "
                       "rounds by one worker process per version (ratios hold under load; the load is in the "
                       "provenance), and each trajectory's largest difference from this checkout's.",
                       ".venv/bin/python benchmarks/odometry_speed.py"),
    "strapdown_rules": ("Strapdown integration rules without the filter",
                        "Dead reckoning on exact IMU data of the 7-lap drive, restarted from the truth every 10 s: "
                        "the sample at the interval's start rotated at its start or its midpoint (the filter's), the "
                        "trapezoid of both ends, the sample stamped at the interval's end; on point samples (the "
                        "simulator's) and on interval averages (what an integrating IMU gives).",
                        ".venv/bin/python benchmarks/strapdown_rules.py"),
    "calibration": ("Online calibration of the radars' mounts and clocks",
                    "A simulated calibration drive with every radar's mount wrong (2 deg yaw, 1 deg pitch, 2 cm lever "
                    "arm) and one radar 5 ms late: each axis's error and standard deviation against the drive's length "
                    "(pitch and the lever arm along z are not taken: these curves turn too little for a sideways "
                    "radar's pitch, and a floor robot never shows the lever arm along z), and the "
                    "odometry's drift (ATE) per drive: the wrong rig calibrated online against the true rig through "
                    "the same filter (calibrate() from the true rig: the issue's 'drift equals the run with the true "
                    "rig'), against the true rig without calibration states, and the wrong rig; the second, iterated "
                    "pass; the true rig with pitch and lever arm z held, and with only those free.",
                    ".venv/bin/python benchmarks/calibration.py"),
    "calibration_states": ("What the calibration states do by themselves",
                           "On the true rig (nothing wrong), the odometry's ATE with calibration states against "
                           "without: every axis free, and each group of axes freed alone (the others held at the "
                           "truth), on 120 s calibration drives; how far each freed axis moved from the truth; the "
                           "Doppler fit's vertical-velocity error per m/s along the boresight and along the array.",
                           ".venv/bin/python benchmarks/calibration_states.py"),
    "calibration_stripmap": ("What calibration buys the image",
                             "Point targets seen by each radar of the miscalibrated rig while the robot sets off into a "
                             "turn (raw frames along the true track), imaged by backprojection on what each odometry run "
                             "believes: the true rig, the wrong rig file, the wrong rig calibrated online (trajectory, "
                             "refined mounts and time offset), and the true rig's odometry with the wrong mounts and "
                             "clock. Peak and main-lobe width against the image on the true rig's odometry.",
                             ".venv/bin/python benchmarks/calibration_stripmap.py"),
    "calibration_time_offset": ("What limits the time-offset calibration",
                                "The Doppler fit's real velocity error per sensor axis against its own standard "
                                "deviation (and the floor that would close the gap), and on 120 s calibration drives "
                                "(2 seeds, 4 radars) the time offset's error, its standard deviation and the NEES of "
                                "the observable axes (yaw, lever x, y, time offset) for the drive's acceleration and "
                                "the filter's velocity floor.",
                                ".venv/bin/python benchmarks/calibration_time_offset.py --configs 1.0:0.008,1.0:0.0045,2.0:0.008"),
    "calibration_unobservable": ("What the axes calibration refuses cost",
                                 "Every radar's mount tilted 1 deg about its array's axis (a sideways radar's pitch) "
                                 "and 2 cm too high, not calibrated (sarbot calibrate refuses the lever arm along z on a floor "
                                 "robot, and the pitch unless the drive turned enough): the "
                                 "geometry (antenna shift, cone angle, Doppler), the odometry's ATE against the true "
                                 "rig's on the calibration drives, and point targets imaged where the robot sets off "
                                 "into a turn against the true rig's image.",
                                 ".venv/bin/python benchmarks/calibration_unobservable.py"),
    "calibration_elevation": ("The Doppler fit's vertical bias from elevation noise",
                              "The fit on measured directions against the fit with the vertical cross-talk removed "
                              "(rio.ego_velocity, 3 deg elevation and 1 deg azimuth noise; the corrected score beside "
                              "them on synthetic detections): the mean vertical error per m/s along the boresight "
                              "against fit_gain's prediction; on calibration drives of 40-90 s (a quicker subset of "
                              "benchmarks/calibration.py's, 2 seeds) roll's error, sigma and NEES (calibrate() from the "
                              "wrong rig), the pitch and lever z that calibrate() from the true rig settles at, and "
                              "calibrated / true-rig-calibrated ATE; benchmarks/odometry.py's one-lap hall drive (three "
                              "seeds) and the real bag through all three fits.",
                              ".venv/bin/python benchmarks/calibration_elevation.py --lengths 40 60 90 --seeds 1 2 "
                              "--odometry"),
    "calibration_pitch": ("A sideways radar's pitch: what turning shows of it, and roll's spread",
                          "Per radar and drive (curves as benchmarks/calibration.py's, tight circles both ways at "
                          "3 rad/s, a straight drive; 40-180 s, 3 seeds): pitch and roll from calibrate() on the "
                          "miscalibrated rig and on the true rig, their errors, standard deviations and NEES, whether "
                          "the pitch was taken; the bound the Doppler fits' own covariances put on them; the fit's "
                          "vertical error per m/s along the boresight and along the array, its z NEES and its "
                          "20-scan-block variance ratio.",
                          ".venv/bin/python benchmarks/calibration_pitch.py"),
    "map_feedback": ("The map corrects the odometry",
                     "Simulated straight drives at 0.4 m/s with the radars' Doppler 2 % low: the odometry's error along "
                     "the track at the end, and every point target's peak in the live map as imaged (before refocus) "
                     "against the map on the true trajectory, without and with the map's velocity errors fed back "
                     "(rio.map_feedback: filter updates plus the Doppler scale learnt from them).",
                     ".venv/bin/python benchmarks/map_feedback.py"),
    "map_feedback_sigma": ("Are the map's velocity sigmas honest?",
                           "Each velocity measurement the live map's refocused tiles give (rio.map_feedback) against "
                           "the truth (rio.map_feedback_truth), on runs of the live daemon test "
                           "(tests/test_map_feedback_live.py) re-imaged from their recordings on their odometry's "
                           "trajectory, all frames and every third (a loaded machine thins them): the NEES (mean "
                           "squared normalised error, 1 where the sigmas are honest) with the sigma now and with the "
                           "fit's residual alone, the tiles of a call jointly and each alone.",
                           ".venv/bin/python benchmarks/map_feedback_sigma.py --seeds --live RUN_DIR --thin 1 3"),
    "map_feedback_settling": ("The odometry settles after a start: when may the map teach the Doppler scale?",
                              "Simulated straight drives (2 s standing, then 0.4 m/s, the radars' Doppler 2 % low), "
                              "the odometry alone, with the unit tests' filter and the live worker's: over a map "
                              "tile's 1.5 s span begun begin_s after the odometry's speed reached 0.1 m/s, how much "
                              "the along-track velocity error changes (a tile cannot see it; a scale does not make "
                              "it) and what the span's velocity error would teach the scale beyond the truth "
                              "(rio.map_feedback's scale_settle_s).",
                              ".venv/bin/python benchmarks/map_feedback_settling.py"),
    "map_feedback_live_drive": ("The Doppler scale the map teaches on the live test's drive, offline",
                                "The live test's drive (tests/test_map_feedback_live.py) with three noise seeds, "
                                "run as the daemon runs it but in one process: odometry on point clouds from the raw "
                                "frames (the live worker's filter), the refocusing map on its poses, each set of tiles "
                                "fed back as it comes; the scale learnt against the truth (+20408 ppm) with "
                                "scale_settle_s off (0) and at 1.5 s (the default since the wild gate), and each "
                                "measurement with its truth (before the wild gate: see the next section).",
                                ".venv/bin/python benchmarks/map_feedback_live_drive.py"),
    "map_feedback_wild": ("Wild tiles on the live test's drive, and the scale learnt without and with the wild gate",
                          "The live test's drive with eight noise seeds, offline as the live workers run it (as "
                          "above): every map measurement against its truth (wild: erring by more than 4 of its sigmas "
                          "and 20 mm/s), with what the live worker can tell it by (its residual's chi2 against the "
                          "filter's velocity sigma, its own sigma and the Doppler scale's at the span's speed: "
                          "rio.map_feedback's wild_gate_chi2) and its tiles' refocus figures (groups, coverage, "
                          "entropy drop: none tells a wild tile); the scale learnt (rio.doppler_scale: the readings' "
                          "weighted mean, widened where they disagree) with the defaults (the wild gate, "
                          "scale_settle_s 1.5, single_tile_settle_s 3) and with single tiles settling as long as "
                          "several (--runs 2 3 add the wild gate alone and the old defaults).",
                          ".venv/bin/python benchmarks/map_feedback_wild.py --runs 0 1"),
    "pointcloud": ("Point clouds from raw frames",
                   "What each live odometry scan costs before the filter sees it, stage by stage.",
                   ".venv/bin/python benchmarks/pointcloud.py"),
    "acquisition": ("Acquisition throughput",
                    "The rate four radars can stream with zero loss through the drivers, the bus and the HDF5 "
                    "recorder, as a multiple of real time.",
                    ".venv/bin/python benchmarks/daemon_recording.py"),
    "batch": ("`sarbot batch` on Dask",
              "A Dask LocalCluster against the same images made one after another in one process.",
              ".venv/bin/python benchmarks/batch.py"),
    "soak": ("Soak: two radars, 30 minutes",
             "The whole daemon (`sarbot run`) at 1x for half an hour on the left pair of radars: loss, memory, lag.",
             ".venv/bin/python benchmarks/soak.py"),
    "soak_4radars": ("Soak: four radars, 30 minutes",
                     "The same with all four radars.",
                     ".venv/bin/python benchmarks/soak.py --radars left_front,left_rear,right_front,right_rear"),
    "soak_quick": ("Soak: two radars, 3 minutes (quick)",
                   "The soak's smoke run.",
                   ".venv/bin/python benchmarks/soak.py --quick"),
    "soak_4radars_quick": ("Soak: four radars, 3 minutes (quick)",
                           "The four-radar soak's smoke run.",
                           ".venv/bin/python benchmarks/soak.py --quick --radars left_front,left_rear,right_front,right_rear"),
    "soak_columns_check": ("Soak: four radars, 90 s, quiet machine",
                           "The four radars at 1x with the map's default polar path for 90 s on the otherwise idle "
                           "machine, after the recorder kept its datasets' handles (it had fallen behind: a third of "
                           "the frames lost on the bus at the commit before, at the same settings). The machine is "
                           "still saturated (`samples`' machine busy near 200 % of 2 cores, the emulated radars' "
                           "senders included), so the map pre-sums nearly every frame beyond its factor.",
                           ".venv/bin/python benchmarks/soak.py --minutes 1.5 --radars left_front,left_rear,"
                           "right_front,right_rear --name columns_check"),
    "soak_4radars_emulator_nice19": ("Soak: four radars, 1 minute, the emulator niced",
                                     "The four radars at 1x for a minute with the emulated hardware (senders, IMU) at "
                                     "nice 19, on the machine as shared with other work: `cpu_accounting` splits the "
                                     "CPU between the daemon, the emulator and the rest of the machine, against what "
                                     "the map needs (stripmap_capacity), and says which kept the map short.",
                                     ".venv/bin/python benchmarks/soak.py --minutes 1 --radars left_front,left_rear,"
                                     "right_front,right_rear --emulator-nice 19 --name 4radars_emulator_nice19"),
    "soak_4radars_1min_loaded": ("Soak: four radars, 1 minute, loaded machine, the cheaper emulator",
                                 "The four radars at 1x for a minute, the emulated hardware at nice 19, after replay's "
                                 "senders were made cheaper (emulator_cost), on the machine as shared with other "
                                 "engineers' work (loaded: see `load_average_end` and `cpu_accounting`'s `other_pct`): "
                                 "not the fair 1x soak, which needs the machine quiet. `cpu_accounting` gives each "
                                 "process's CPU per frame received and what the map got against what it needs.",
                                 ".venv/bin/python benchmarks/soak.py --minutes 1 --radars left_front,left_rear,"
                                 "right_front,right_rear --emulator-nice 19 --name 4radars_1min_loaded"),
    "soak_4radars_5min_amd_avx2": ("Soak: four radars, 5 minutes, the emulator niced, on the AMD EPYC VM (issue 34 item 5)",
                                   "The same run as the previous section (soak.py, four radars at 1x for 5 minutes, the "
                                   "emulated hardware at nice 19, the machine otherwise quiet) on the VM as it was on "
                                   "2026-11-26 from 20:45 UTC: an AMD EPYC with AVX2 and no AVX-512, where the drivers took "
                                   "1.7x the CPU per frame they took on the AVX-512 VM and the machine was full. Written "
                                   "under the name below (the JSON's provenance has the name it was run with).",
                                   ".venv/bin/python benchmarks/soak.py --minutes 5 --radars left_front,left_rear,"
                                   "right_front,right_rear --emulator-nice 19 --name 4radars_5min_amd_avx2"),
    "soak_4radars_5min_amd_cheaper_drivers": ("Soak: four radars, 5 minutes, on the AMD EPYC VM with the cheaper drivers "
                                              "and recorder (issue 34 item 5)",
                                              "The previous section's run again on the same VM after the radar drivers' "
                                              "and the recorder's CPU per frame was cut (benchmarks/driver_cpu_per_frame.py): "
                                              "the same command, the machine otherwise quiet.",
                                              ".venv/bin/python benchmarks/soak.py --minutes 5 --radars left_front,left_rear,"
                                              "right_front,right_rear --emulator-nice 19 --name 4radars_5min_amd_cheaper_drivers"),
    "soak_4radars_5min_amd_riocpu": ("Soak: four radars, 5 minutes, on the AMD EPYC VM with the cheaper odometry "
                                     "(issue 34 item 5)",
                                     "The previous section's run again on the same VM after the odometry worker's CPU per "
                                     "scan was cut (benchmarks/odometry_cpu_per_scan.py): the same command, the machine "
                                     "otherwise quiet.",
                                     ".venv/bin/python benchmarks/soak.py --minutes 5 --radars left_front,left_rear,"
                                     "right_front,right_rear --emulator-nice 19 --name 4radars_5min_amd_riocpu"),
    "soak_4radars_5min_amd_catch_up_0.6": ("Soak: four radars, 5 minutes, the map's catch-up starting at 0.6 s "
                                           "(tried, not kept)",
                                           "The previous section's run with `CATCH_UP_START_S` set to 0.6 s in "
                                           "acquisition/workers/stripmap.py (0.3 s on main) for this run only, "
                                           "started right after it: the map's lag rose to the new start and it "
                                           "pre-summed as many frames (see docs/benchmark-notes.md).",
                                           "edit CATCH_UP_START_S = 0.6, then .venv/bin/python benchmarks/soak.py "
                                           "--minutes 5 --radars left_front,left_rear,right_front,right_rear "
                                           "--emulator-nice 19 --name 4radars_5min_amd_catch_up_0.6"),
    "soak_4radars_5min_amd_presum": ("Soak: four radars, 5 minutes, on the AMD EPYC VM with the cheaper map frame "
                                     "(issue 34 item 5; quiet)",
                                     "The same command after the map's CPU per frame was cut (stripmap_presum), the "
                                     "lead's re-run with nothing else running: nothing lost, and half the frames "
                                     "pre-summed beyond the factor; every process took 13-14 % more CPU a frame than "
                                     "in the riocpu soak (the VM's hour), the map's cut aside (see "
                                     "docs/benchmark-notes.md).",
                                     ".venv/bin/python benchmarks/soak.py --minutes 5 "
                                     "--radars left_front,left_rear,right_front,right_rear --emulator-nice 19 "
                                     "--name 4radars_5min_amd_presum"),
    "soak_4radars_5min_amd_gro": ("Soak: four radars, 5 minutes, on the AMD EPYC VM with batched radar receive "
                                  "(issue 34 item 5 met; quiet)",
                                  "The same command after wave 3m: the drivers receive and assemble a batch of "
                                  "datagrams per system call (UDP GRO), the recorder writes whole checksummed chunks, "
                                  "the point clouds' CFAR is one numba pass. The lead's run with nothing else "
                                  "running: nothing lost, no invalid frame, 185 of 24,000 frames (0.8 %) pre-summed "
                                  "beyond the factor, the map's lag 0.12 s median, 60 % of the machine idle (see "
                                  "docs/benchmark-notes.md).",
                                  ".venv/bin/python benchmarks/soak.py --minutes 5 "
                                  "--radars left_front,left_rear,right_front,right_rear --emulator-nice 19 "
                                  "--name 4radars_5min_amd_gro"),
    "soak_4radars_5min_amd_beams": ("Soak: four radars, 5 minutes, on the AMD EPYC VM after the strip map's beams cut "
                                    "(issue 34 item 5; quiet)",
                                    "The same command after wave 3n (the map's beams 1.12x less CPU per frame). The "
                                    "lead's run with nothing else running, in a slower hour of the VM (every other "
                                    "process took 11-27 % more CPU per frame than in soak_4radars_5min_amd_gro): "
                                    "nothing lost, no invalid frame, 1,070 of 24,000 frames (4.5 %) pre-summed beyond "
                                    "the factor, the map's lag 0.13 s median, 43 % of the machine idle (see "
                                    "docs/benchmark-notes.md).",
                                    ".venv/bin/python benchmarks/soak.py --minutes 5 "
                                    "--radars left_front,left_rear,right_front,right_rear --emulator-nice 19 "
                                    "--name 4radars_5min_amd_beams"),
    "soak_4radars_5min_emulator_nice19": ("Soak: four radars, 5 minutes, the emulator niced (issue 34 item 5)",
                                          "The four radars at 1x for 5 minutes with the cheaper emulated hardware at "
                                          "nice 19, to be run on the otherwise quiet machine: frames pre-summed beyond "
                                          "the configured factor (`map_frames_presummed_more` against all "
                                          "frames, `frames_sent_per_radar` x 4; goal at most 5 %), nothing dropped, the map's lag "
                                          "below 2 s; `cpu_accounting` says whether the machine was quiet.",
                                          ".venv/bin/python benchmarks/soak.py --minutes 5 --radars left_front,"
                                          "left_rear,right_front,right_rear --emulator-nice 19 --name "
                                          "4radars_5min_emulator_nice19"),
    "emulator_cost": ("The emulated radars' CPU per frame",
                      "Replay's sender as it was (HDF5 read every lap, a datagram at a time, a sendto each) against "
                      "now (raw chunk reads after the first lap, packed datagrams with CRCs kept across laps, UDP "
                      "segmentation), interleaved in one process on the soak's scene, part by part (read, encode, "
                      "send); the same datagrams arrive. With the IMU emulator's CPU, the four-radar emulator's share "
                      "of a core at 1x.",
                      ".venv/bin/python benchmarks/emulator_cost.py"),
    "driver_cpu_per_frame": ("A radar driver's and the recorder's CPU per frame",
                             "The radar driver's code at the commit before wave 3j (baseline) against now, interleaved "
                             "in one process on the same datagrams of the reference waveform (716,800-byte frames, 498 "
                             "SRF1 datagrams): the frame assembly alone, UdpReceiver.receive alone, and the driver loop "
                             "(receive, assemble, publish to a subscriber) at 1x in a thread of its own; and the recorder "
                             "storing one radar's frames with a flush every 10. CPU per frame; "
                             "the machine was shared (load in the provenance), so the ratios taken in the same rounds "
                             "are the figures, not the milliseconds.",
                             ".venv/bin/python benchmarks/driver_cpu_per_frame.py"),
    "driver_cpu_per_frame_gro": ("A radar driver's CPU per frame with UDP GRO",
                                 "The radar driver's code at main before wave 3m (aa20a74, one recvmsg and one feed a "
                                 "datagram) against now (UDP GRO: a batch of up to 64 datagrams a receive, fed with "
                                 "feed_segments), interleaved in one process on the same datagrams of the reference "
                                 "waveform sent segmented as replay sends them: the receive alone (the baseline's "
                                 "receive against receive_segments), the driver loop (receive, assemble, publish to a "
                                 "subscriber) at 1x in a thread of its own; the assembly and the recorder, the same code "
                                 "in both, as controls. CPU per frame; the machine was shared (load in the provenance), "
                                 "so the ratios taken in the same rounds are the figures, not the milliseconds.",
                                 ".venv/bin/python benchmarks/driver_cpu_per_frame.py --baseline aa20a74 --rounds 8 "
                                 "--frames 20 --name driver_cpu_per_frame_gro"),
    "stream_segments": ("Frame assembly from GRO batches of datagrams",
                        "The radar streams' frame assembly fed one datagram at a time (feed) against batches of "
                        "datagrams received back to back (feed_segments, as UDP GRO hands them over: 64 and 8 at a "
                        "time), interleaved in one process on the same datagrams: SRF1 on the reference waveform "
                        "(716,800-byte frames, 498 version 2 datagrams), DCA1000 on 524,288-byte frames in 1,466-byte "
                        "datagrams. CPU per frame; the frames are compared byte for byte with what was sent. The "
                        "machine was shared (load in the provenance), so the ratios taken in the same rounds are the "
                        "figures, not the milliseconds.",
                        ".venv/bin/python benchmarks/stream_segments.py"),
    "recorder_cpu_per_frame": ("The supervisor's recorder: CPU per frame on the four-radar soak's mix, and its RSS",
                               "The recorder's code (with its RecordingWriter and ReceiveDelay) at main before wave 3m "
                               "(aa20a74, baseline) against now, interleaved in one process on the soak's mix: four "
                               "radars' 716,800-byte frames every 52 ms, IMU batches at 400 Hz, an event every 2 s, a "
                               "flush every 10 ticks; CPU per radar frame, fsync thread included. The files are "
                               "compared dataset, attribute and stored ADC chunk. RSS: each version alone over 5800 "
                               "ticks (5 minutes of data) with a part every 60 s. The machine was shared (load in "
                               "the provenance), so the ratios taken in the same rounds are the figures.",
                               ".venv/bin/python benchmarks/recorder_cpu_per_frame.py"),
    "odometry_cpu_per_scan": ("The odometry worker's CPU per radar scan",
                              "The odometry worker's code (the worker, the point clouds, the trajectory writer) at "
                              "main before wave 3m's numba CFAR (aa20a74, baseline) against now, interleaved in one process on the demo "
                              "drive (four radars, 10 s, the IMU at 400 Hz): every message through "
                              "OdometryWorker.handle, the trajectory file written; CPU of the worker's thread per "
                              "scan made into a point cloud (every second frame). The trajectories and point "
                              "clouds of the two are compared; the machine was shared (load in the provenance), "
                              "so the ratios taken in the same rounds are the figures, not the milliseconds.",
                              ".venv/bin/python benchmarks/odometry_cpu_per_scan.py"),
    "soak_direct_2m": ("Soak: 2 m aperture, direct kernel",
                       "The live map at a 2 m aperture with the direct kernel.",
                       ".venv/bin/python benchmarks/soak.py --minutes 3 --map-args \"--map-aperture 2\" --name direct_2m"),
    "soak_ffbp_2m": ("Soak: 2 m aperture, FFBP blocks",
                     "The live map at a 2 m aperture with FFBP blocks.",
                     ".venv/bin/python benchmarks/soak.py --minutes 8 --map-args \"--map-algorithm ffbp --map-aperture 2\" "
                     "--name ffbp_2m"),
    "paper/report": ("The reference study (evaluation on simulated data)",
                     "Range and cross-range resolution against theory with the true and the odometry's trajectory, "
                     "vibration side lobes and their inverse, coherent integration gain, where imaging fails, and "
                     "autofocus; the full write-up is [its report](results/paper/report.md).",
                     "sarbot experiment paper"),
}
