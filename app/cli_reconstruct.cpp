// Flags of the reconstruct stage's subcommands: register, reconstruct (run by
// app/cmd_reconstruct.cpp). Both bind straight to their jobs.
#include "app/cli.h"

namespace s2r::cli {

namespace {

void add_register(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand(
      "register",
      "Register all views at once (Ceres): point-to-plane between every overlapping pair, coarse to fine.\n"
      "Input: a session (depth or scanner points; initial poses from --calibration's turntable axis and\n"
      "the table angles, or the session's given poses) or Stanford range scans (--stanford CONF).\n"
      "Writes OUT/poses.json, OUT/report.json, OUT/views.csv, OUT/pairs.csv, OUT/convergence.csv/png\n"
      "(RMS and pose error against seconds) and, for --stanford, OUT/<CONF> in the input's own conventions.");
  auto a = std::make_shared<RegisterArgs>();
  RegisterJob& job = a->job;
  sub->add_option("session", job.session, "capture session folder");
  sub->add_option("--stanford", job.stanford_conf, "Stanford .conf with its range scans beside it");
  sub->add_option("--calibration", job.calibration, "calibration file (turntable axis, intrinsics)");
  sub->add_option("--out", job.out, "output folder")->required();
  sub->add_option("--mode", a->mode,
                  "free (every pose free; slides reported) or turntable (rotation about the calibrated axis by the "
                  "table angle plus a small correction)")
      ->check(CLI::IsMember({"free", "turntable"}))
      ->capture_default_str();
  sub->add_option("--perturb", a->perturb, "DEG,M: start from the input poses turned by DEG and shifted by M metres");
  sub->add_option("--seed", job.seed, "random seed of --perturb")->capture_default_str();
  sub->add_option("--fixed", job.fixed_name, "name of the view held fixed (default: the first)");
  sub->add_option("--voxels", a->voxels, "coarse-to-fine voxel sizes in metres, e.g. 0.004,0.002,0.001 (default: from the extent)");
  sub->add_option("--table-sigma-deg", job.table_sigma_deg, "turntable mode: table angle repeatability")->capture_default_str();
  sub->add_option("--threads", job.options.threads, "worker threads (0 = all cores)")->capture_default_str();
  sub->add_flag_callback("--no-flip", [&job] { job.options.try_flip = false; }, "do not try flagged views turned by 180 deg");
  sub->callback([a, &chosen] { chosen = a; });
}

void add_export(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand(
      "export",
      "A capture or a model for other tools (docs/formats.md, Exports):\n"
      "  colmap SESSION      cameras.txt, images.txt, points3D.txt + images/ (COLMAP's text model:\n"
      "                      cam_from_world, pixel centres at i+0.5; points: the depth frames fused on a\n"
      "                      voxel grid, with the frames that saw each as its track)\n"
      "  nerfstudio SESSION  transforms.json + images/ (+ masks/): per-frame intrinsics and distortion,\n"
      "                      camera-to-world in OpenGL axes, for NeRF and Gaussian-splatting trainers\n"
      "  gltf MODEL          FILE.glb: the patch mesh (or fused surface) with a texture atlas baked from\n"
      "                      the photos, metres, +Y up, the capture's cameras as glTF cameras\n"
      "  web MODEL           a static folder drawing the microfacet billboards with depth clipping in\n"
      "                      WebGL2 (index.html; orbit, zoom, pan, touch, the capture's cameras)\n"
      "Poses as reconstruct resolves them. A folder OUT must be new or empty; nothing appears until whole.");
  auto a = std::make_shared<ExportArgs>();
  sub->add_option("format", a->format, "colmap | nerfstudio | gltf")->required()->check(CLI::IsMember({"colmap", "nerfstudio", "gltf", "web"}));
  sub->add_option("input", a->input, "the session (colmap, nerfstudio) or the model (gltf, web)")->required();
  sub->add_option("--out", a->job.out, "folder to create (colmap, nerfstudio, web) or FILE.glb (gltf)")->required();
  sub->add_option("--poses", a->job.poses, "registered poses (s2r register)");
  sub->add_option("--calibration", a->job.calibration, "calibration file (intrinsics, depth extrinsic, turntable axis)");
  sub->add_option("--max-points", a->job.max_points, "colmap: at most this many points (the most observed first)")
      ->capture_default_str();
  sub->add_option("--point-voxel", a->job.point_voxel_m, "colmap: grid the depth points are fused on, metres (0: extent/256)")
      ->capture_default_str();
  sub->add_option("--mesh", a->gltf.mesh, "gltf: patch (the octree's patch mesh) or surface (the fused surface)")
      ->check(CLI::IsMember({"patch", "surface"}))->capture_default_str();
  sub->add_option("--atlas", a->gltf.atlas_max, "gltf: the texture atlas's side at most, texels")->capture_default_str();
  sub->add_option("--cell", a->gltf.max_cell, "gltf: texels per triangle cell side at most")->capture_default_str();
  sub->add_option("--threads", a->gltf.threads, "gltf: baking threads (0 = all cores)")->capture_default_str();
  sub->add_option("--background", a->background, "web: white, black or R,G,B (0-255 levels); default: the model's own background (the capture's, e.g. white for NeRF-synthetic), else black, as s2r render");
  sub->add_option("--budget-mib", a->web.budget_mib, "web: the camera images' payload at most, MiB (reduced by an integer "
                                                      "factor above it)")->capture_default_str();
  sub->add_option("--report", a->report, "report path (default OUT/report.json; gltf: OUT's name + .report.json)");
  sub->callback([a, &chosen] { chosen = a; });
}

void add_reconstruct(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand(
      "reconstruct",
      "Fuse a session's registered views into a model of microfacet billboards.\n"
      "Depth is fused into a sparse signed-distance volume (OpenVDB); against a uniform backdrop the\n"
      "silhouettes add a visual hull, whose voxels that depth does not explain become fuzzy facets\n"
      "(hair, strands); without depth the hull alone gives the geometry. Every voxel with evidence becomes\n"
      "a facet; reliable voxels keep the voxel size, unreliable and fuzzy regions merge into facets twice\n"
      "as large. Each camera's image is stored with the distance to the fused surface along every ray.\n"
      "Poses: --poses, else the session's given poses, else --calibration's turntable axis and the table\n"
      "angles, else the synthetic rig's ground truth.\n"
      "Writes OUT/model.json, facets.bin, facet_cameras.bin, cameras/NNNN.exr (RGBA + Z), surface.ply\n"
      "and report.json (seconds per step, facets, memory, voxel sizes, predicted texel error, skipped work).");
  auto a = std::make_shared<ReconstructArgs>();
  ReconstructJob& job = a->job;
  sub->add_option("session", job.session, "capture session folder")->required();
  sub->add_option("--out", job.out, "model folder")->required();
  sub->add_option("--poses", job.poses, "registered poses (s2r register)");
  sub->add_option("--calibration", job.calibration, "calibration file (intrinsics, depth extrinsic, turntable axis)");
  sub->add_option("--voxel", a->voxel,
                  "facet size w in metres, or 'auto': the largest w whose texel error bound (w/2) sin(gap/2) stays under "
                  "--target-error pixels at the cameras' distance, halved for reliable regions")
      ->capture_default_str();
  sub->add_option("--target-error", job.target_error_px, "on-screen texel error in pixels that --voxel auto keeps under")
      ->capture_default_str();
  sub->add_option("--geometry", a->geometry,
                  "depth (fusion), hull (silhouettes only), both, or auto (depth, plus the hull against a uniform backdrop)")
      ->check(CLI::IsMember({"auto", "depth", "hull", "both"}))
      ->capture_default_str();
  sub->add_option("--holdout", a->holdout, "I,J,...: frames left out entirely (for evaluation)");
  sub->add_option("--truncation", job.truncation_voxels, "signed-distance truncation in voxels")->capture_default_str();
  sub->add_flag_callback("--uniform", [&job] { job.per_region = false; },
                         "one facet size everywhere (no larger facets for unreliable regions)");
  sub->add_flag_callback("--no-textures", [&job] { job.textures = false; },
                         "do not write the per-camera RGBA + depth textures (the cameras' depth is then cast only where "
                         "the facets' visibility needs it)");
  sub->add_flag("--photo-depth", job.photo_depth,
               "captures without depth (--geometry hull): search each camera's depth behind the visual hull by "
               "photo-consistency (normalized cross-correlation with its nearest cameras) and carve the hull where "
               "two cameras show it empty: concavities no silhouette shows");
  sub->add_option("--fit", job.fit_seconds,
                  "seconds to fit billboards to the training photos (opacity, footprint, offset and view-dependent "
                  "colour per facet, by differentiable rasterization; writes splats.bin and fit.csv, the training "
                  "error against seconds); 0: no fit")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  sub->add_option("--fit-epochs", job.fit_epochs,
                  "also stop the fit after this many passes over the photos, its stages sharing them as they share "
                  "the seconds: the same model on a slower or busier machine (give --fit ample seconds); 0: seconds only")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  sub->add_option("--fit-max-facets", job.fit_max_facets,
                  "the fit's refinement splits the most used facets up to this many (half before its last stage); "
                  "each costs 68 bytes in the model (--fit-sh 1) and its share of every step")
      ->check(CLI::Range(size_t(1000), size_t(20000000)))
      ->capture_default_str();
  sub->add_option("--fit-stage-growth", job.fit_stage_growth,
                  "the fit runs coarse to fine in stages (the grid halving at each); each stage gets this many times "
                  "the seconds of the one before (above 1: the finest stage the most; seconds moved there trade PSNR for "
                  "SSIM, docs/cli.md)")
      ->check(CLI::Range(0.25, 16.0))
      ->capture_default_str();
  sub->add_option("--fit-sh", job.fit_sh_degree, "spherical-harmonic degree of the fitted colour (0: the same from every side)")
      ->check(CLI::Range(0, 2))
      ->capture_default_str();
  sub->add_flag("--fit-random-background", job.fit_random_background,
               "views with a matte (an RGBA data set): each fit step moves the photo onto a random colour under its "
               "matte and composites the facets on the same, so opacity is fitted to the matte");
  sub->add_option("--fit-ssim", job.fit_ssim_weight,
                  "the fit's loss: (1 - W) x the colour term (--fit-loss) + W x (1 - SSIM), as 3D Gaussian Splatting mixes in D-SSIM (0.2 chosen on lego's val split); 0: the colour term alone")
      ->check(CLI::Range(0.0, 0.95))
      ->capture_default_str();
  sub->add_option("--fit-loss", job.fit_loss,
                  "the loss's colour term: l2 (the squared error) or l1 (the absolute error, as 3D Gaussian Splatting fits)")
      ->check(CLI::IsMember({"l2", "l1"}))
      ->capture_default_str();
  sub->add_option("--fit-pixel-filter", job.fit_pixel_filter_px2,
                  "the fitted billboards' pixel filter, pixels^2: each footprint is drawn convolved with a Gaussian of "
                  "this variance, its energy kept (Mip-Splatting's 2D filter), so a facet smaller than a pixel draws "
                  "as its share of the pixel, not as speckle; 0: none")
      ->check(CLI::Range(0.0, 4.0))
      ->capture_default_str();
  sub->add_option("--fit-split", job.fit_split,
                  "which facets refinement splits first: usage (the most pixel weight) or gradient (the largest mean "
                  "pull on their image position, as 3D Gaussian Splatting densifies)")
      ->check(CLI::IsMember({"usage", "gradient"}))
      ->capture_default_str();
  sub->add_option("--fit-depth", job.fit_depth_weight,
                  "captures with depth: the fit's loss adds W x the squared distance (in voxels) of each pixel's opacity "
                  "from the fused depth surface, so facets stay on the surface the depth camera saw; 0: colour alone")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  sub->add_option("--fit-snapshots", job.fit_snapshots,
                  "S,T,...: also write the fit as it was at these seconds (splats_<S>s.bin; s2r eval --splats)")
      ->delimiter(',');
  sub->add_option("--threads", job.threads, "worker threads (0 = all cores)")->capture_default_str();
  sub->callback([a, &chosen] { chosen = a; });
}

}  // namespace

void add_reconstruct_commands(CLI::App& app, Chosen& chosen) {
  add_register(app, chosen);
  add_reconstruct(app, chosen);
  add_export(app, chosen);
}

}  // namespace s2r::cli
