// Runs a Flamenco job compiler script under Node with stand-ins for the
// globals Flamenco's Manager gives it (author, path, print), and prints the
// compiled job as JSON: tasks in order with type, commands and dependencies.
//
//   node flamenco_harness.js farm/flamenco/ember.js '{"frames": "1-4", ...}'
"use strict";
const fs = require("fs");
const nodePath = require("path");
const vm = require("vm");

const [script, settingsJson] = process.argv.slice(2);
const tasks = [];

class Task {
    constructor(name, type) {
        if (typeof name !== "string" || !name || typeof type !== "string" || !type) {
            throw new Error(`author.Task needs a name and a type, got ${name}, ${type}`);
        }
        this.name = name;
        this.type = type;
        this.commands = [];
        this.dependencies = [];
    }
    addCommand(command) {
        if (!command || typeof command.name !== "string") {
            throw new Error("addCommand needs an author.Command");
        }
        this.commands.push(command);
    }
    addDependency(task) {
        if (!(task instanceof Task)) {
            throw new Error("addDependency needs an author.Task");
        }
        this.dependencies.push(task.name);
    }
}

const context = {
    author: {
        Task: (name, type) => new Task(name, type),
        Command: (name, parameters) => ({ name, parameters }),
    },
    path: {
        join: (...parts) => nodePath.posix.join(...parts),
        dirname: (p) => nodePath.posix.dirname(p),
        basename: (p) => nodePath.posix.basename(p),
        stem: (p) => nodePath.posix.basename(p, nodePath.posix.extname(p)),
    },
    print: (...args) => process.stderr.write(args.join(" ") + "\n"),
};
vm.createContext(context);
vm.runInContext(fs.readFileSync(script, "utf8"), context, { filename: script });

const jobType = vm.runInContext("JOB_TYPE", context);
const job = {
    name: "test job",
    settings: JSON.parse(settingsJson),
    addTask(task) {
        if (!(task instanceof Task)) {
            throw new Error("job.addTask needs an author.Task");
        }
        if (tasks.some((t) => t.name === task.name)) {
            throw new Error(`two tasks named ${task.name}`);
        }
        for (const dep of task.dependencies) {
            if (!tasks.some((t) => t.name === dep)) {
                throw new Error(`${task.name} depends on ${dep}, which was not added before it`);
            }
        }
        tasks.push(task);
    },
};
// Defaults the Manager fills in from JOB_TYPE before compiling.
for (const setting of jobType.settings) {
    if (job.settings[setting.key] === undefined && setting.default !== undefined) {
        job.settings[setting.key] = setting.default;
    }
    if (setting.required && job.settings[setting.key] === undefined) {
        console.log(JSON.stringify({ error: `missing required setting ${setting.key}` }));
        process.exit(0);
    }
}
try {
    context.compileJob(job);
} catch (err) {
    console.log(JSON.stringify({ error: String(err) }));
    process.exit(0);
}
console.log(JSON.stringify({ label: jobType.label, keys: jobType.settings.map((s) => s.key), tasks }));
