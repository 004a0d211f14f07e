// A fleetbus robot in Node.js on amqplib, built from the AsyncAPI document alone (contract.mjs).
//
//   node tests/peers/robot.mjs < config.json
//
// config.json: {"role": "explorer" | "warden", "asyncapi": "DIR/asyncapi.json", "ca": "ca.pem",
// "url": "<the URL `fleetbus users add` printed>" or "url_file": "<the file it saved it in>",
// "other": "<another account's name>", "timeout_s": 60}. The URL (it holds the password) comes
// on stdin or from its file, never in argv. The broker is
// verified with the CA file given here: a `cacertfile` in the URL is a RabbitMQ/Erlang parameter
// that amqplib ignores, like every client that is not RabbitMQ's.
//
// The explorer publishes a hazard and a status with publisher confirms, then one message for each
// way of breaking the contract; the warden publishes its localisation first (the hazard gate),
// waits for the hazard's announcement in its inbox, and calls the service `hazard.open`. Each
// step is printed as one JSON line; any failure ends the program with status 1.

import { randomUUID } from "node:crypto";
import { readFileSync } from "node:fs";

import amqp from "amqplib";

import { Contract } from "./contract.mjs";

const config = JSON.parse(readFileSync(0, "utf8"));
if (config.url === undefined && config.url_file) config.url = readFileSync(config.url_file, "utf8").trim();
const contract = new Contract(config.asyncapi);
const timeoutMs = (config.timeout_s ?? 60) * 1000;
// whatever hangs, the program ends: no step may outlast its own timeout, nor the whole run three
setTimeout(() => {
  process.stderr.write(`gave up after ${(3 * timeoutMs) / 1000} s\n`);
  process.exit(2);
}, 3 * timeoutMs).unref();

function say(line) {
  process.stdout.write(`${JSON.stringify(line)}\n`);
}

function within(promise, what) {
  let timer;
  const late = new Promise((_, reject) => {
    timer = setTimeout(() => reject(new Error(`no ${what} within ${timeoutMs / 1000} s`)), timeoutMs);
  });
  return Promise.race([promise, late]).finally(() => clearTimeout(timer));
}

async function connect() {
  const server = contract.server();
  const url = new URL(config.url);
  if (url.protocol !== `${server.protocol}:`) {
    throw new Error(`the document's server speaks ${server.protocol}, the URL ${url.protocol}`);
  }
  const connection = await amqp.connect(config.url, { ca: [readFileSync(config.ca)], timeout: timeoutMs });
  connection.on("error", (error) => say({ step: "connection-error", message: error.message }));
  say({ step: "connected", protocol: server.protocol, port: url.port, document_port: server.variables.port.default });
  return { connection, robot: decodeURIComponent(url.username) };
}

// A confirm channel whose publish resolves once the broker confirmed the message, and fails when
// the broker nacks it or returns it (`mandatory`: no queue took it).
async function confirming(connection) {
  const channel = await connection.createConfirmChannel();
  const returned = new Map();
  channel.on("return", (message) => {
    returned.set(message.properties.messageId, `${message.fields.replyCode} ${message.fields.replyText}`);
  });
  channel.on("error", (error) => say({ step: "channel-error", code: error.code, message: error.message }));
  const publish = async (exchange, routingKey, body, options) => {
    await within(
      new Promise((resolve, reject) => {
        channel.publish(exchange, routingKey, body, options, (error) => (error ? reject(error) : resolve()));
      }),
      `confirm of ${routingKey}`,
    );
    if (returned.has(options.messageId)) {
      throw new Error(`${routingKey} was returned: ${returned.get(options.messageId)}`);
    }
  };
  return { channel, publish };
}

// An event of `type` as the document builds it: required envelope fields, the body checked against
// the payload schema, the properties from the message's `x-amqp-properties`.
function eventMessage(route, known, extra = {}) {
  const envelope = contract.envelope(route.schema, known, extra);
  return { envelope, body: Buffer.from(JSON.stringify(envelope)) };
}

function mustBeValid(schema, value, what) {
  const { valid, errors } = contract.check(schema, value);
  if (!valid) throw new Error(`${what} is not valid against ${schema}: ${errors.join("; ")}`);
}

async function explorer() {
  const { connection, robot } = await connect();
  const { publish } = await confirming(connection);
  const hazard = contract.event("hazard", robot);
  const status = contract.event("status", robot);
  const epoch = contract.newEpoch(hazard.schema);
  let seq = 0;
  const next = (route, body) => {
    const messageId = randomUUID();
    const message = eventMessage(route, { robot_id: robot, epoch, seq: seq++, body }, { message_id: messageId });
    return { ...message, messageId };
  };
  const good = {
    hazard: next(hazard, {
      pose: { x: 4.2, y: -1.5 },
      description: "Gas leak (reported by a Node.js robot)",
      detected_at: new Date().toISOString(),
    }),
    status: next(status, { battery_percent: 76.5, pose: { x: 4.0, y: -1.0 }, processing_rate_hz: 5 }),
  };
  for (const [type, message] of Object.entries(good)) {
    const route = type === "hazard" ? hazard : status;
    mustBeValid(route.schema, message.envelope, type);
    if (message.body.length > route.maxBytes) throw new Error(`${type} is over ${route.maxBytes} bytes`);
    await publish(route.exchange, route.routingKey, message.body, route.options({ message_id: message.messageId }));
    say({ step: "published", type, epoch, seq: message.envelope.seq, message_id: message.messageId });
  }

  // Each way of breaking the contract, and the outcome the document gives for it.
  const reasons = contract.reasons();
  const expect = (reason) => {
    if (!(reason in reasons)) throw new Error(`the document lists no dead-letter reason ${reason}`);
    return reason;
  };
  const broken = [];
  {
    const message = next(hazard, { ...good.hazard.envelope.body });
    const bodySchema = contract.resolve(hazard.schema).properties.body.$ref;
    const [field] = contract.resolve(bodySchema).required;
    delete message.envelope.body[field];
    message.body = Buffer.from(JSON.stringify(message.envelope));
    if (contract.check(hazard.schema, message.envelope).valid) throw new Error("the schema misses a missing field");
    broken.push({ case: "missing-field", field, route: hazard, message, options: {}, expect: expect("schema") });
  }
  {
    const message = next(status, { ...good.status.envelope.body });
    broken.push({ case: "content-type", route: status, message, options: { contentType: "text/plain" }, expect: expect("content-type") });
  }
  {
    const message = next(status, { ...good.status.envelope.body });
    message.body = Buffer.from(JSON.stringify(message.envelope) + " ".repeat(status.maxBytes));
    broken.push({ case: "oversize", route: status, message, options: {}, expect: expect("too-large") });
  }
  {
    const message = next(status, { ...good.status.envelope.body });
    broken.push({ case: "transient", route: status, message, options: { deliveryMode: 1 }, expect: expect("not-persistent") });
  }
  for (const item of broken) {
    if (item.case !== "missing-field") mustBeValid(item.route.schema, item.message.envelope, item.case);
    const options = { ...item.route.options({ message_id: item.message.messageId }), ...item.options };
    await publish(item.route.exchange, item.route.routingKey, item.message.body, options);
    say({ step: "malformed", case: item.case, field: item.field, message_id: item.message.messageId, expect: item.expect, seq: item.message.envelope.seq });
  }

  // A forged user_id: the document says the broker closes the channel on it.
  {
    const forge = await connection.createConfirmChannel();
    const closed = new Promise((resolve) => forge.once("error", resolve));
    const message = next(status, { ...good.status.envelope.body });
    const options = { ...status.options({ message_id: message.messageId }), userId: config.other };
    const confirmed = await new Promise((resolve) => {
      forge.publish(status.exchange, status.routingKey, message.body, options, (error) => resolve(!error));
    });
    const error = await within(closed, "channel close after a forged user_id");
    say({ step: "forged", case: "user-id", user_id: config.other, confirmed, code: error.code, message: error.message });
  }
  await connection.close();
}

async function warden() {
  const { connection, robot } = await connect();
  const { publish } = await confirming(connection);
  const localisation = contract.event("localisation", robot);
  const epoch = contract.newEpoch(localisation.schema);
  const messageId = randomUUID();
  const known = { robot_id: robot, epoch, seq: 0, body: { localised: true, pose: { x: 0.5, y: 0.5 } } };
  const { envelope, body } = eventMessage(localisation, known, { message_id: messageId });
  mustBeValid(localisation.schema, envelope, "localisation");
  await publish(localisation.exchange, localisation.routingKey, body, localisation.options({ message_id: messageId }));
  say({ step: "localised", epoch, seq: 0, message_id: messageId });

  const inbox = contract.inbox(robot);
  const reading = await connection.createChannel();
  await reading.prefetch(10);
  const notificationType = contract.resolve("#/components/messages/notification").contentType;
  const announced = await within(
    new Promise((resolve, reject) => {
      reading.consume(
        inbox.queue,
        (message) => {
          try {
            if (message.properties.contentType !== notificationType) {
              throw new Error(`a notification of content type ${message.properties.contentType}`);
            }
            const note = JSON.parse(message.content.toString("utf8"));
            mustBeValid(inbox.schema, note, "a notification");
            if (inbox.ack) reading.ack(message);
            if (note.topic === "hazard") resolve(note);
          } catch (error) {
            reject(error);
          }
        },
        { noAck: !inbox.ack },
      );
    }),
    "hazard announcement in the inbox",
  );
  say({ step: "announced", notification: announced });

  const service = contract.service("hazard.open", robot);
  const calls = await connection.createChannel();
  calls.on("return", (message) => say({ step: "returned", routing_key: message.fields.routingKey }));
  const correlationId = randomUUID();
  const reply = new Promise((resolve) => {
    calls.consume(
      service.replyQueue,
      (message) => {
        if (message.properties.correlationId === correlationId) resolve(JSON.parse(message.content.toString("utf8")));
      },
      { noAck: service.replyNoAck },
    );
  });
  const params = {};
  mustBeValid(service.params, params, "the hazard.open parameters");
  const options = service.options({ correlation_id: correlationId, expiration: String(timeoutMs) });
  calls.publish(service.exchange, service.routingKey, Buffer.from(JSON.stringify(params)), options);
  const answer = await within(reply, "reply to hazard.open");
  mustBeValid(service.reply, answer, "the hazard.open reply");
  say({ step: "service", method: "hazard.open", reply: answer });
  await connection.close();
}

const roles = { explorer, warden };
roles[config.role]().catch((error) => {
  process.stderr.write(`${error.stack ?? error}\n`);
  process.exit(1);
});
