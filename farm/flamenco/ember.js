// Flamenco job type for Ember: frame chunks, or frames split into sample shards
// merged exactly by the last task of each frame.
//
// Install: copy this file into the Manager's `scripts/` folder (next to the
// flamenco-manager executable) and restart it.  Workers need Blender with the
// Ember add-on installed and enabled (tools/install_addon.py); for the
// split-samples mode also an Ember checkout with its Python (variables
// {ember_python} and {ember_root} in flamenco-manager.yaml), which runs
// `python -m farm merge`.  Every shard renders a disjoint range of sample
// indices of the same seed; the add-on saves its film sums
// (addon/shards.py) and the merge checks them and counts each planned range
// once.

const JOB_TYPE = {
    label: "Ember Render",
    description: "Render frames with Ember; optionally split each frame's samples over several workers",
    settings: [
        { key: "frames", type: "string", required: true,
          eval: "f'{C.scene.frame_start}-{C.scene.frame_end}'",
          description: "Frames to render, e.g. '1-250' or '1,5,10-12'" },
        { key: "chunk_size", type: "int32", default: 1, propargs: {min: 1},
          description: "Frames per render task (without sample splitting)" },
        { key: "samples", type: "int32", default: 0, propargs: {min: 0},
          eval: "C.scene.ember.samples",
          description: "Samples per pixel (0: the scene's setting; required when splitting)" },
        { key: "split_samples", type: "int32", default: 1, propargs: {min: 1},
          description: "Shards per frame: each renders a disjoint range of samples, merged afterwards" },
        { key: "render_output_root", type: "string", subtype: "dir_path", required: true,
          description: "Folder for the frames (frame_####.exr) and the shards (shards/)" },
        { key: "render_threads", type: "int32", default: 0, propargs: {min: 0},
          description: "Render threads per task (0: every core)" },
        { key: "blendfile", type: "string", required: true, visible: "web",
          description: "Path of the blend file to render" },
        { key: "ember_python", type: "string", default: "{ember_python}", visible: "hidden" },
        { key: "ember_root", type: "string", default: "{ember_root}", visible: "hidden" },
    ]
};

function compileJob(job) {
    const settings = job.settings;
    const frames = emberFrames(settings.frames);
    const outDir = settings.render_output_root;
    if (!outDir) {
        throw "Ember: render_output_root is not set";
    }
    const split = settings.split_samples || 1;
    if (split > 1) {
        if (!(settings.samples >= split)) {
            throw `Ember: splitting into ${split} shards needs samples >= ${split} (got ${settings.samples})`;
        }
        for (const frame of frames) {
            emberSplitFrame(job, settings, frame, outDir);
        }
        return;
    }
    for (const chunk of emberChunks(frames, settings.chunk_size || 1)) {
        const task = author.Task(`render-${chunk[0]}-${chunk[chunk.length - 1]}`, "blender");
        task.addCommand(emberRender(settings, chunk, path.join(outDir, "frame_####"), null));
        job.addTask(task);
    }
}

// K shard tasks of one frame, then its merge task (depending on all of them).
function emberSplitFrame(job, settings, frame, outDir) {
    const shardDir = path.join(outDir, "shards");
    const scratch = path.join(outDir, ".farm", "tmp", `frame-${frame}`, "shard_####");
    const ranges = emberSampleRanges(settings.samples, settings.split_samples);
    const shardTasks = [];
    for (const [start, end] of ranges) {
        const task = author.Task(`shard-${frame}-s${start}-${end}`, "blender");
        task.addCommand(emberRender(settings, [frame], scratch, [shardDir, start, end - start]));
        job.addTask(task);
        shardTasks.push(task);
    }
    const merge = author.Task(`merge-${frame}`, "misc");
    const pattern = path.join(shardDir, `frame_${emberPad(frame, 6)}.s*.npz`);
    const plan = ranges.map(([a, b]) => `${a}-${b}`).join(",");
    merge.addCommand(author.Command("exec", {
        exe: settings.ember_python,
        args: ["-c", `import sys; sys.path.insert(0, ${JSON.stringify(settings.ember_root)}); ` +
                     "from farm.__main__ import main; sys.exit(main(sys.argv[1:]))",
               "merge", pattern, "--plan", plan,
               "-o", path.join(outDir, `frame_${emberPad(frame, 4)}.exr`)],
    }));
    for (const task of shardTasks) {
        merge.addDependency(task);
    }
    job.addTask(merge);
}

// A blender-render command; shard = [folder, first sample, sample count] or null.
function emberRender(settings, frames, output, shard) {
    return author.Command("blender-render", {
        exe: "{blender}",
        exeArgs: "{blenderArgs}",
        argsBefore: [],
        blendfile: settings.blendfile,
        args: [
            "-E", "EMBER",
            "--render-output", output,
            "--render-format", "OPEN_EXR",
            "--python-expr", emberSetup(settings, shard),
            "--render-frame", emberFrameArg(frames),
        ],
    });
}

// Python run inside Blender after the file is loaded, before rendering:
// the same as farm/commands.py setup_code().
function emberSetup(settings, shard) {
    const lines = [
        "import bpy, os",
        "s = bpy.context.scene",
        "s.render.engine = 'EMBER'",
        `s.ember.threads = ${settings.render_threads || 0}`,
        "st = s.render.image_settings",
        "if hasattr(st, 'media_type'): st.media_type = 'IMAGE'",
        "st.file_format = 'OPEN_EXR'",
        "st.color_depth = '32'",
        "s.render.use_file_extension = True",
    ];
    if (settings.samples > 0) {
        lines.push(`s.ember.samples = ${settings.samples}`);
    }
    if (shard) {
        const [folder, start, count] = shard;
        lines.push(`os.environ['EMBER_SHARD_DIR'] = ${JSON.stringify(folder)}`);
        lines.push(`os.environ['EMBER_SHARD_START'] = '${start}'`);
        lines.push(`os.environ['EMBER_SHARD_SAMPLES'] = '${count}'`);
    }
    // Exit with status 1 when Ember reports an error: Blender itself would
    // exit 0 and save a black frame.
    lines.push(
        "import sys as _s",
        "def _ember_farm_check(*_args):",
        "    for _name, _mod in list(_s.modules.items()):",
        "        _log = getattr(_mod, 'RENDER_LOG', None) if _name.split('.')[-1] == 'engine' else None",
        "        if _log and _log[-1].get('error'):",
        "            print('EMBER-FARM-ERROR:', _log[-1]['error'], flush=True)",
        "            import os as _o",
        "            _o._exit(1)",
        "bpy.app.handlers.render_post.append(_ember_farm_check)");
    return lines.join("\n") + "\n";
}

// '1-10,20' -> [1, ..., 10, 20] (sorted, distinct).
function emberFrames(text) {
    const frames = new Set();
    for (const part of String(text).replace(/\s+/g, "").split(",")) {
        const m = /^(-?\d+)(?:(?:-|\.\.)(-?\d+))?$/.exec(part);
        if (!m) {
            throw `Ember: bad frame range '${part}' in '${text}'`;
        }
        const first = parseInt(m[1], 10);
        const last = m[2] === undefined ? first : parseInt(m[2], 10);
        if (last < first) {
            throw `Ember: frame range '${part}' ends before it starts`;
        }
        for (let f = first; f <= last; f++) {
            frames.add(f);
        }
    }
    return Array.from(frames).sort((a, b) => a - b);
}

// Runs of consecutive frames, at most size long.
function emberChunks(frames, size) {
    const out = [];
    let run = [];
    for (const frame of frames) {
        if (run.length && (frame !== run[run.length - 1] + 1 || run.length === size)) {
            out.push(run);
            run = [];
        }
        run.push(frame);
    }
    if (run.length) {
        out.push(run);
    }
    return out;
}

// [0, samples) in `parts` disjoint ranges, as farm/plan.py sample_ranges().
function emberSampleRanges(samples, parts) {
    const ranges = [];
    for (let i = 0; i < parts; i++) {
        ranges.push([Math.floor(samples * i / parts), Math.floor(samples * (i + 1) / parts)]);
    }
    return ranges;
}

function emberFrameArg(frames) {
    const first = frames[0], last = frames[frames.length - 1];
    if (frames.length > 1 && last - first + 1 === frames.length) {
        return `${first}..${last}`;
    }
    return frames.join(",");
}

function emberPad(n, width) {
    return String(n).padStart(width, "0");
}
