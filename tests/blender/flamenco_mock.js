// A stand-in for Flamenco Manager's job compiler, for tests: runs a job type script with the
// globals Flamenco documents (author.Task, author.Command, path.*, print, job.settings,
// job.addTask) and prints the compiled tasks as JSON. The checks Flamenco's worker would do
// on a "blender-render" command (parameter names and types) are done here too.
// Usage: node tests/flamenco_mock.js SCRIPT.js '{"settings": {...}}'
"use strict";
const fs = require("fs");
const nodePath = require("path");
const vm = require("vm");

const [scriptFile, jobJson] = process.argv.slice(2);
const jobIn = JSON.parse(jobJson);

// The worker's blender-render parameters (internal/worker/command_blender.go): exe a non-empty
// string, exeArgs an optional string, argsBefore and args lists of strings, blendfile a
// string (empty: Blender starts without a file).
const BLENDER_RENDER = { exe: "string", exeArgs: "string", argsBefore: "strings",
                         blendfile: "string", args: "strings" };

function checkCommand(name, params) {
    if (name !== "blender-render") return;
    for (const key of Object.keys(params)) {
        if (!(key in BLENDER_RENDER)) throw new Error(`blender-render: unknown parameter ${key}`);
    }
    for (const [key, kind] of Object.entries(BLENDER_RENDER)) {
        const v = params[key];
        if (key === "exeArgs" && v === undefined) continue;
        const ok = kind === "string" ? typeof v === "string"
            : Array.isArray(v) && v.every((x) => typeof x === "string");
        if (!ok) throw new Error(`blender-render: ${key} must be ${kind}, got ${JSON.stringify(v)}`);
    }
    if (params.exe === "") throw new Error("blender-render: missing 'exe' parameter");
}

// The command line the worker runs (variables such as {blender} left unexpanded).
function commandLine(params) {
    const cli = [params.exe];
    if (params.exeArgs) cli.push(...params.exeArgs.split(/\s+/).filter((x) => x));
    cli.push(...params.argsBefore);
    if (params.blendfile !== "") cli.push(params.blendfile);
    cli.push(...params.args);
    return cli;
}

const tasks = [];
const author = {
    Task(name, type) {
        const task = { name: name, type: type, commands: [], dependencies: [] };
        task.addCommand = (cmd) => { task.commands.push(cmd); };
        task.addDependency = (other) => {
            if (!tasks.includes(other)) throw new Error("dependency on a task not added to the job");
            task.dependencies.push(other.name);
        };
        return task;
    },
    Command(name, parameters) {
        checkCommand(name, parameters);
        const cmd = { name: name, parameters: parameters };
        if (name === "blender-render") cmd.cli = commandLine(parameters);
        return cmd;
    },
};
const path = {  // Flamenco's path helpers work on forward-slash paths
    join: (...parts) => nodePath.posix.join(...parts),
    dirname: (p) => nodePath.posix.dirname(p),
    basename: (p) => nodePath.posix.basename(p),
    stem: (p) => nodePath.posix.parse(p).name,
};
const job = {
    settings: jobIn.settings, metadata: jobIn.metadata || {}, created: new Date(0),
    addTask(task) { tasks.push(task); },
};
const printed = [];
const context = vm.createContext({ author, path, job, print: (...a) => printed.push(a.join(" ")) });
vm.runInContext(fs.readFileSync(scriptFile, "utf8"), context, { filename: scriptFile });
const jobType = vm.runInContext("typeof JOB_TYPE === 'undefined' ? null : JOB_TYPE", context);
if (jobType === null || typeof jobType !== "object" || !Array.isArray(jobType.settings)) {
    throw new Error("the script defines no JOB_TYPE with settings");
}
try {
    vm.runInContext("compileJob(job)", context);
} catch (e) {
    // Flamenco reports a thrown string or Error as the job's compile error.
    process.stdout.write(JSON.stringify({ error: String(e) }));
    process.exit(0);
}
const out = tasks.map((t) => ({ name: t.name, type: t.type, commands: t.commands,
                                dependencies: t.dependencies }));
process.stdout.write(JSON.stringify({ job_type: jobType, tasks: out, printed }));
