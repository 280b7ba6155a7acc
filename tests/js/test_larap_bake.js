// Run: node tests/js/test_larap_bake.js
// The Flamenco job type flamenco/larap-bake.js, compiled with small stand-ins for the globals the
// Flamenco Manager gives job compiler scripts (author.Task, author.Command, path, print); checks
// the task graph: optional bind first, one bake task per chunk, the merge depending on all of them.
"use strict";
const assert = require("assert");
const fs = require("fs");
const nodePath = require("path");
const vm = require("vm");

const SCRIPT = nodePath.join(__dirname, "..", "..", "flamenco", "larap-bake.js");

function flamencoContext() {
    const author = {
        Task(name, type) {
            return {
                name, type, commands: [], dependencies: [],
                addCommand(cmd) { this.commands.push(cmd); },
                addDependency(task) { this.dependencies.push(task); },
            };
        },
        Command(name, parameters) { return { name, parameters }; },
    };
    const path = { join: (...p) => nodePath.posix.join(...p), dirname: nodePath.posix.dirname,
                   basename: nodePath.posix.basename };
    const ctx = vm.createContext({ author, path, print: () => {} });
    vm.runInContext(fs.readFileSync(SCRIPT, "utf8"), ctx, { filename: SCRIPT });
    return ctx;
}

function compile(settings) {
    const ctx = flamencoContext();
    const tasks = [];
    const job = { name: "test", created: new Date(0), settings: {
        frames: "1-10", chunk_size: 4, preroll: 3, objects: '["Body", "Prop, A"]', bake_output: "/farm/bake",
        device: "file", mode: "warm", warm_tol: 1e-7, tol: 1e-10, max_iterations: 1000, bind: false, bind_frame: 1,
        blender_cmd: "{blender}", blendfile: "/farm/shot.blend", ...settings },
        addTask(t) { tasks.push(t); } };
    ctx.compileJob(job);
    return { tasks, ctx };
}

function argsOf(task) {
    assert.strictEqual(task.commands.length, 1);
    const cmd = task.commands[0];
    assert.strictEqual(cmd.name, "blender-render");
    const a = Array.from(cmd.parameters.args);  // an array of the script's realm: copy it into ours
    const k = a.indexOf("--python-exit-code");
    assert.ok(k >= 0 && a[k + 1] === "1", `${task.name}: --python-exit-code 1 missing`);
    assert.ok(k < a.indexOf("--"), `${task.name}: --python-exit-code after --`);
    assert.deepStrictEqual(a.slice(0, 2), ["--addons", "larap_blender"]);
    return a.slice(a.indexOf("--") + 1);
}

function opt(args, name) {
    const i = args.indexOf(name);
    return i < 0 ? undefined : args[i + 1];
}

const tests = {
    "job type declares its settings"() {
        const ctx = flamencoContext();
        const jt = vm.runInContext("JOB_TYPE", ctx);
        const keys = jt.settings.map((s) => s.key);
        for (const k of ["frames", "chunk_size", "preroll", "objects", "bake_output", "device", "bind", "blendfile"]) {
            assert.ok(keys.includes(k), `setting ${k} missing`);
        }
        assert.strictEqual(typeof ctx.compileJob, "function");
    },

    "one bake task per chunk, the merge depends on all"() {
        const { tasks } = compile({});
        assert.deepStrictEqual(tasks.map((t) => t.name),
            ["larap-chunk-1-4", "larap-chunk-5-8", "larap-chunk-9-10", "larap-merge"]);
        const chunks = tasks.slice(0, 3);
        const merge = tasks[3];
        assert.ok(tasks.every((t) => t.type === "blender"));
        assert.deepStrictEqual(merge.dependencies, chunks);
        for (const t of chunks) {
            assert.deepStrictEqual(t.dependencies, []);
            assert.strictEqual(t.commands[0].parameters.blendfile, "/farm/shot.blend");
            const a = argsOf(t);
            assert.deepStrictEqual(a.slice(0, 4), ["--object", "Body", "--object", "Prop, A"]);
            assert.strictEqual(opt(a, "--job-frames"), "1-10");
            assert.strictEqual(opt(a, "--preroll"), "3");
            assert.strictEqual(opt(a, "--out"), "/farm/bake");
            assert.strictEqual(Number(opt(a, "--warm-tol")), 1e-7);
            assert.strictEqual(opt(a, "--device"), undefined);
        }
        assert.deepStrictEqual(chunks.map((t) => opt(argsOf(t), "--chunk")), ["1-4", "5-8", "9-10"]);
        assert.ok(chunks[0].commands[0].parameters.args.includes("import larap.farm.blender_chunk as m; m.main()"));
        const m = argsOf(merge);
        assert.deepStrictEqual(m.slice(0, 2), ["merge", "/farm/shot.blend"]);
        assert.strictEqual(opt(m, "--frames"), "1-10");
        assert.strictEqual(opt(m, "--chunk-size"), "4");
        assert.strictEqual(opt(m, "--preroll"), "3");
        assert.strictEqual(opt(m, "--mode"), "warm");
        assert.strictEqual(opt(m, "--out"), "/farm/bake");
    },

    "bind task first, chunks bake the bound copy"() {
        const { tasks } = compile({ bind: true, bind_frame: 7, frames: "3-8", chunk_size: 3, device: "cuda",
                                    objects: "Body, Arm" });
        assert.deepStrictEqual(tasks.map((t) => t.name),
            ["larap-bind", "larap-chunk-3-5", "larap-chunk-6-8", "larap-merge"]);
        const [bind, c1, c2, merge] = tasks;
        assert.deepStrictEqual(bind.dependencies, []);
        assert.strictEqual(bind.commands[0].parameters.blendfile, "/farm/shot.blend");
        const b = argsOf(bind);
        assert.deepStrictEqual(b, ["--object", "Body", "--object", "Arm", "--frame", "7", "--save-as",
                                   "/farm/bake/bound.blend"]);
        for (const t of [c1, c2]) {
            assert.deepStrictEqual(t.dependencies, [bind]);
            assert.strictEqual(t.commands[0].parameters.blendfile, "/farm/bake/bound.blend");
            assert.strictEqual(opt(argsOf(t), "--device"), "cuda");
        }
        assert.deepStrictEqual(merge.dependencies, [c1, c2]);
    },

    "rest mode: no pre-roll, no warm tolerance"() {
        const { tasks } = compile({ mode: "rest", chunk_size: 5 });
        assert.strictEqual(tasks.length, 3);
        for (const t of tasks.slice(0, 2)) {
            const a = argsOf(t);
            assert.strictEqual(opt(a, "--mode"), "rest");
            assert.strictEqual(opt(a, "--preroll"), undefined);
            assert.strictEqual(opt(a, "--warm-tol"), undefined);
        }
    },

    "warm tolerance: 1e-7 by default, 0 for the add-on's own solve, always explicit in warm mode"() {
        for (const [settings, want] of [[{ warm_tol: undefined }, "1e-7"], [{ warm_tol: 0 }, "0"],
                                        [{ warm_tol: 1e-6 }, "0.000001"]]) {
            const { tasks } = compile(settings);
            for (const t of tasks) {
                assert.strictEqual(opt(argsOf(t), "--warm-tol"), want, `${t.name} ${JSON.stringify(settings)}`);
            }
        }
        const ctx = flamencoContext();
        const setting = vm.runInContext("JOB_TYPE", ctx).settings.find((s) => s.key === "warm_tol");
        assert.strictEqual(setting.default, 1e-7);
    },

    "one chunk when the chunk is larger than the range"() {
        const { tasks } = compile({ frames: "5", chunk_size: 100 });
        assert.deepStrictEqual(tasks.map((t) => t.name), ["larap-chunk-5-5", "larap-merge"]);
    },

    "bad settings are refused with a message"() {
        const bad = [[{ frames: "1,5-10" }, /one range/], [{ frames: "9-2" }, /empty/],
                     [{ objects: "[]" }, /no objects/], [{ objects: "[oops" }, /JSON/],
                     [{ chunk_size: 0 }, /chunk_size/], [{ preroll: -1 }, /preroll/],
                     [{ bake_output: "" }, /bake_output/], [{ mode: "fast" }, /mode/]];
        for (const [settings, pattern] of bad) {
            assert.throws(() => compile(settings), (e) => pattern.test(String(e)), JSON.stringify(settings));
        }
    },
};

let failed = 0;
for (const [name, fn] of Object.entries(tests)) {
    try {
        fn();
        console.log(`ok   ${name}`);
    } catch (e) {
        failed++;
        console.log(`FAIL ${name}\n${e && e.stack ? e.stack : e}`);
    }
}
console.log(`${Object.keys(tests).length - failed} passed, ${failed} failed`);
process.exit(failed ? 1 : 0);
