// SPDX-License-Identifier: GPL-3.0-or-later
// Flamenco job type: one heavy Pathlight frame split into sample ranges, one render task per
// range, then a merge task (in Blender, through the Pathlight add-on) that depends on them all.
// Copy into the `scripts/` directory next to flamenco-manager (docs/farm.md).

const JOB_TYPE = {
    label: "Pathlight Split Frame",
    settings: [
        { key: "frame", type: "int32", required: true, eval: "C.scene.frame_current",
          description: "Frame to render" },
        { key: "samples", type: "int32", required: true, eval: "C.scene.pathlight.samples",
          description: "Samples of the whole frame" },
        { key: "pieces", type: "int32", default: 4, propargs: {min: 1, max: 4096},
          description: "Tasks to split the samples into" },
        { key: "render_output_root", type: "string", subtype: "dir_path", required: true,
          visible: "submission", description: "Directory of the partial renders" },
        { key: "blendfile", type: "string", required: true, visible: "web",
          description: "Path of the Blend file to render" },
    ]
};

// Balanced split of [0, samples) into at most `pieces` consecutive, disjoint ranges: the
// first (samples % pieces) ranges get one sample more. Never an empty range.
function sampleRanges(samples, pieces) {
    const n = Math.min(pieces, samples);
    const base = Math.floor(samples / n), extra = samples % n;
    const ranges = [];
    let offset = 0;
    for (let k = 0; k < n; k++) {
        const count = base + (k < extra ? 1 : 0);
        ranges.push({ offset: offset, count: count });
        offset += count;
    }
    return ranges;
}

function compileJob(job) {
    const s = job.settings;
    const samples = Number(s.samples), pieces = Number(s.pieces), frame = Number(s.frame);
    if (!Number.isInteger(samples) || samples < 1) throw `samples must be a positive integer, not ${s.samples}`;
    if (!Number.isInteger(pieces) || pieces < 1) throw `pieces must be a positive integer, not ${s.pieces}`;
    if (!Number.isInteger(frame)) throw `frame must be an integer, not ${s.frame}`;
    const ranges = sampleRanges(samples, pieces);
    const renderTasks = [], parts = [];
    for (let k = 0; k < ranges.length; k++) {
        const r = ranges[k];
        const output = path.join(s.render_output_root, `part${k}_######`);
        parts.push([output, r.offset, r.count]);
        const task = author.Task(`samples-${r.offset}-${r.offset + r.count}`, "blender");
        task.addCommand(author.Command("blender-render", {
            exe: "{blender}",
            exeArgs: "{blenderArgs}",
            argsBefore: [],
            blendfile: s.blendfile,
            args: [
                // After the file is loaded, before the render: this task's sample range, all
                // of it (no adaptive sampling, no time limit: the merge weighs each piece by
                // its range), raw
                // 32-bit float EXR (the merge needs linear data; composite after merging;
                // no --render-format, which could reset the colour depth).
                "--python-expr", [
                    "import bpy",
                    "sc = bpy.context.scene",
                    `sc.pathlight.samples = ${r.count}`,
                    `sc.pathlight.sample_offset = ${r.offset}`,
                    `sc.pathlight.frame_samples = ${samples}`,  // the frame's total: blue noise's chunks
                    "sc.pathlight.use_adaptive_sampling = False",
                    "sc.pathlight.time_limit = 0",
                    "sc.render.use_compositing = False",
                    "sc.render.image_settings.file_format = 'OPEN_EXR'",
                    "sc.render.image_settings.color_depth = '32'",
                ].join("; "),
                "--render-output", output,
                "--render-frame", `${frame}`,
            ],
        }));
        job.addTask(task);
        renderTasks.push(task);
    }

    // The merge: Blender without a file (the add-on is enabled in the workers' Blender) runs
    // farm_merge.merge_frame of the add-on, found through its scene settings' module (the
    // add-on's package name depends on where it was installed).
    const merge = author.Task("merge", "blender");
    merge.addCommand(author.Command("blender-render", {
        exe: "{blender}",
        exeArgs: "{blenderArgs}",
        argsBefore: [],
        blendfile: "",
        args: [
            "--python-expr", [
                "import bpy, importlib",
                "pkg = type(bpy.context.scene.pathlight).__module__.rpartition('.')[0]",
                "merge = importlib.import_module(pkg + '.farm_merge').merge_frame",
                `merge(${frame}, ${JSON.stringify(parts)}, ` +
                `${JSON.stringify(path.join(s.render_output_root, "frame_######"))})`,
            ].join("; "),
        ],
    }));
    for (const t of renderTasks) merge.addDependency(t);
    job.addTask(merge);
}
