// SPDX-License-Identifier: GPL-3.0-or-later
// Flamenco job type "larap-bake": a LARAP animation bake split into chunks on the farm.
// Install: copy this file into the `scripts` folder next to the flamenco-manager executable and
// restart the Manager (docs/farm.md). Workers need Blender with the LARAP add-on installed
// (scripts/install_addon), which carries the larap.farm scripts every task runs.
//
// Task graph: [larap-bind] -> larap-chunk-<a>-<b> (one per chunk) -> larap-merge.
// Each task runs headless Blender with `--python-exit-code 1` (a failing script otherwise exits 0
// and the Worker would mark the task done). The arguments match python/larap/farm/command.py.

const JOB_TYPE = {
    label: "LARAP Bake",
    description: "Bake LARAP poses of bound meshes over a frame range into PC2 caches (Mesh Cache modifier)",
    settings: [
        { key: "frames", type: "string", required: true, eval: "f'{C.scene.frame_start}-{C.scene.frame_end}'",
          description: "Frame range to bake, e.g. '1-240' (one range)" },
        { key: "chunk_size", type: "int32", default: 25, propargs: { min: 1 },
          description: "Frames per bake task (each task starts Blender and binds once)" },
        { key: "preroll", type: "int32", default: 3, propargs: { min: 0 },
          description: "Frames solved before each chunk and discarded, so its warm start matches one machine's" },
        { key: "objects", type: "string", required: true,
          eval: "__import__('json').dumps([o.name for o in C.selected_objects if o.type == 'MESH'])",
          description: "Meshes to bake: a JSON list of names, or names separated by commas" },
        { key: "bake_output", type: "string", subtype: "dir_path", required: true,
          description: "Folder of the bake: chunks/ while baking, then <object>.pc2 and bake.json" },
        { key: "device", type: "string", default: "file", choices: ["file", "cpu", "cuda", "auto"],
          description: "Solver device ('file': each object's own setting)" },
        { key: "mode", type: "string", default: "warm", choices: ["warm", "rest"],
          description: "warm: frames warm-start within a chunk; rest: every frame from rest (independent of the chunking, slower)" },
        { key: "warm_tol", type: "float", default: 1e-7, visible: "submission",
          description: "Tolerance of warm-started solves (0: the add-on's own final solve)" },
        { key: "tol", type: "float", default: 1e-10, visible: "submission",
          description: "Tolerance of solves from rest (a chunk's first frame)" },
        { key: "max_iterations", type: "int32", default: 1000, visible: "submission",
          description: "Iteration cap of solves to a tolerance" },
        { key: "bind", type: "bool", default: false,
          description: "Bind the objects first (at the bind frame) and bake a bound copy of the file" },
        { key: "bind_frame", type: "int32", eval: "C.scene.frame_start", visible: "submission",
          description: "Frame whose target transforms become rest when binding" },
        { key: "blender_cmd", type: "string", default: "{blender}", visible: false },
        { key: "blendfile", type: "string", required: true, visible: false, description: "The .blend to bake" },
    ],
};

const ADDON_ARGS = ["--addons", "larap_blender", "--python-exit-code", "1", "--python-expr"];
const CHUNK_EXPR = "import larap.farm.blender_chunk as m; m.main()";
const BIND_EXPR = "import larap.farm.blender_bind as m; m.main()";
const CLI_EXPR = "import larap.farm.cli as c; c.blender_main()";

function compileJob(job) {
    const s = job.settings;
    const [first, last] = parseFrameRange(s.frames);
    const chunkSize = positiveInt("chunk_size", s.chunk_size, 1);
    const preroll = positiveInt("preroll", s.preroll === undefined ? 3 : s.preroll, 0);
    const objects = parseObjects(s.objects);
    if (!s.bake_output) throw "larap-bake: setting 'bake_output' (the bake folder) is empty";
    if (!s.blendfile) throw "larap-bake: setting 'blendfile' is empty";
    const mode = s.mode || "warm";
    if (mode !== "warm" && mode !== "rest") throw `larap-bake: mode must be 'warm' or 'rest', got '${mode}'`;

    let blendfile = s.blendfile;
    let bindTask = null;
    if (s.bind) {
        blendfile = path.join(s.bake_output, "bound.blend");
        const args = objectArgs(objects).concat(["--frame", String(s.bind_frame === undefined ? first : s.bind_frame),
                                                 "--save-as", blendfile]);
        bindTask = blenderTask("larap-bind", s, s.blendfile, BIND_EXPR, args);
        job.addTask(bindTask);
    }

    // The solver's arguments, shared by the chunks and the merge (which checks them in every chunk).
    const solver = ["--mode", mode, "--tol", String(s.tol || 1e-10), "--max-iterations", String(s.max_iterations || 1000),
                    "--out", s.bake_output];
    // Always explicit in warm mode, so chunks and merge agree; 0: the add-on's own final solve.
    if (mode === "warm") solver.push("--warm-tol", String(s.warm_tol === undefined || s.warm_tol === null ? 1e-7 : s.warm_tol));
    const range = `${first}-${last}`;

    const chunkTasks = [];
    for (const [a, b] of planChunks(first, last, chunkSize, mode === "warm" ? preroll : 0)) {
        const args = objectArgs(objects).concat(["--job-frames", range, "--chunk", `${a}-${b}`], solver);
        if (mode === "warm" && preroll > 0) args.push("--preroll", String(preroll));
        if (s.device && s.device !== "file") args.push("--device", s.device);
        const task = blenderTask(`larap-chunk-${a}-${b}`, s, blendfile, CHUNK_EXPR, args);
        if (bindTask) task.addDependency(bindTask);
        job.addTask(task);
        chunkTasks.push(task);
    }

    const mergeArgs = ["merge", blendfile].concat(objectArgs(objects),
        ["--frames", range, "--chunk-size", String(chunkSize), "--preroll", String(preroll)], solver);
    if (s.device && s.device !== "file") mergeArgs.push("--device", s.device);
    const mergeTask = blenderTask("larap-merge", s, blendfile, CLI_EXPR, mergeArgs);
    for (const t of chunkTasks) mergeTask.addDependency(t);
    job.addTask(mergeTask);
}

// One task running headless Blender with the add-on and a larap.farm entry point.
function blenderTask(name, settings, blendfile, expr, args) {
    const task = author.Task(name, "blender");
    task.addCommand(author.Command("blender-render", {
        exe: settings.blender_cmd || "{blender}",
        exeArgs: "{blenderArgs}",
        argsBefore: ["-b"],
        blendfile: blendfile,
        args: ADDON_ARGS.concat([expr, "--"], args),
    }));
    return task;
}

function objectArgs(objects) {
    const args = [];
    for (const name of objects) args.push("--object", name);
    return args;
}

// [start, end, solveStart] per chunk, as python/larap/farm/plan.py plans them.
function planChunks(first, last, size, preroll) {
    const chunks = [];
    for (let a = first; a <= last; a += size) {
        chunks.push([a, Math.min(a + size - 1, last), Math.max(first, a - preroll)]);
    }
    return chunks;
}

function parseFrameRange(text) {
    const m = /^\s*(-?\d+)\s*(?:(?:-|\.\.)\s*(-?\d+)\s*)?$/.exec(String(text));
    if (!m) throw `larap-bake: frames must be one range like '1-240', got '${text}'`;
    const first = parseInt(m[1], 10);
    const last = m[2] === undefined ? first : parseInt(m[2], 10);
    if (last < first) throw `larap-bake: frame range '${text}' is empty`;
    return [first, last];
}

function parseObjects(text) {
    let names;
    const t = String(text || "").trim();
    if (t.startsWith("[")) {
        try { names = JSON.parse(t); } catch (e) { throw `larap-bake: objects is not a JSON list: ${e}`; }
    } else {
        names = t.split(",").map((n) => n.trim());
    }
    names = names.filter((n) => typeof n === "string" && n.length > 0);
    if (names.length === 0) throw "larap-bake: no objects to bake (select the bound meshes before submitting)";
    return names;
}

function positiveInt(name, value, minimum) {
    const v = Number(value);
    if (!Number.isInteger(v) || v < minimum) throw `larap-bake: ${name} must be an integer >= ${minimum}, got '${value}'`;
    return v;
}
