// Run by the mongo image once, on the first boot of an empty mongo-data volume, as the root user:
// the application's user, which may read and write fleetbus's database and nothing else.
const password = process.env.FLEETBUS_MONGODB_PASSWORD;
if (!password) {
  throw new Error("FLEETBUS_MONGODB_PASSWORD is not set");
}
db.getSiblingDB("fleetbus").createUser({
  user: "fleetbus",
  pwd: password,
  roles: [{ role: "readWrite", db: "fleetbus" }],
});
