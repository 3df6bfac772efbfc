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

const BLENDER_RENDER = { exe: "string", exeArgs: "string", argsBefore: "strings",
                         blendfile: "string", args: "strings" };

function checkCommand(name, params) {
    if (name !== "blender-render") return;
    for (const key of Object.keys(params)) {
        if (!(key in BLENDER_RENDER)) throw new Error(`blender-render: unknown parameter ${key}`);
    }
    for (const [key, kind] of Object.entries(BLENDER_RENDER)) {
        const v = params[key];
        const ok = kind === "string" ? typeof v === "string"
            : Array.isArray(v) && v.every((x) => typeof x === "string");
        if (!ok) throw new Error(`blender-render: ${key} must be ${kind}, got ${JSON.stringify(v)}`);
    }
}

const tasks = [];
const author = {
    Task(name, type) {
        const task = { name: name, type: type, commands: [], dependencies: [] };
        task.addCommand = (cmd) => { task.commands.push(cmd); };
        task.addDependency = (other) => { task.dependencies.push(other.name); };
        return task;
    },
    Command(name, parameters) {
        checkCommand(name, parameters);
        return { name: name, parameters: parameters };
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
