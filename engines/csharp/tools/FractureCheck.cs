// FractureCheck - conformance driver of the C# reader (used by the fracture tests).
//
//   mono FractureCheck.exe HEADER BINARY [--names] [--describe] [--skip-crc] [--compact] [--structure] < impacts
//   mono FractureCheck.exe --bench ROUNDS HEADER BINARY [--compact] < impacts
//
// Same line protocol as engines/c/tools/fracture_check.c: impacts are 7 hex IEEE-754 doubles
// (point, impulse, threshold or "-"); answers "ok <site> <num_groups> g ... b ... a ... d ..."
// or "error <status>"; a file that does not load prints "load-error <message>" and exits with 2.
// Each impact is also projected without displacements: an answer that differs prints "error
// inconsistent". --compact loads without the jump table (the other projection path).
// Damage states (docs/FORMAT.md section 12), as the C driver: "start new" or "start <e health bits>"
// (loaded through StateFromBytes; "start-error <status>" keeps the previous state) makes every later
// impact a Hit on that state; --structure prints after every answer
// "structure c <cracked bonds> y <anchored flags> h <health bits, saved through StateToBytes>".
// --describe prints section 12's data as the C driver does: "describe f <features bits: stress 1, anchors 2,
// damage 4> c <CrackLevel bits> r <DamageRate bits> y <anchored flags, or -> n <segments of each bond> s
// <coordinates of every bond's segments>".
// Levels (docs/FORMAT.md section 14): the "body", "object" and "hit" lines and --children of
// tests/levels_support.py (HitPiece, ObjectPieces).
// --bench times every impact ROUNDS times (Stopwatch around each Project call, groups only) and
// prints "median_ns <x> p99_ns <x> calls <n>", like fracture_bench.c.
//
// MIT licence, Copyright (c) fracture developers.

using System;
using System.IO;
using System.Globalization;
using System.Text;
using Fracture;

static class FractureCheck
{
    static double FromBits(string hex)
    {
        return BitConverter.Int64BitsToDouble(unchecked((long)Convert.ToUInt64(hex, 16)));
    }

    static string Bits(double value)
    {
        return BitConverter.DoubleToInt64Bits(value).ToString("x16");
    }

    static int Main(string[] args)
    {
        bool names = Array.IndexOf(args, "--names") >= 0, skipCrc = Array.IndexOf(args, "--skip-crc") >= 0;
        bool compact = Array.IndexOf(args, "--compact") >= 0;
        int bench = Array.IndexOf(args, "--bench"), rounds = 0;
        if (bench >= 0 && (bench + 1 >= args.Length || !int.TryParse(args[bench + 1], out rounds) || rounds < 1))
            bench = -2;
        string[] paths = Array.FindAll(args, a => !a.StartsWith("--") && (bench < 0 || a != args[bench + 1]));
        if (paths.Length != 2 || bench == -2)
        {
            Console.Error.WriteLine("usage: FractureCheck [--bench ROUNDS] HEADER BINARY [--names] [--skip-crc] [--compact] < impacts");
            return 64;
        }
        FractureRuntime runtime;
        string error;
        if (!FractureRuntime.TryLoad(File.ReadAllBytes(paths[0]), File.ReadAllBytes(paths[1]), out runtime, out error,
                                     !skipCrc, compact))
        {
            Console.WriteLine("load-error " + error);
            return 2;
        }
        if (bench >= 0)
            return Bench(runtime, rounds);
        var output = new StringBuilder();
        if (names)
        {
            output.Append("names");
            foreach (string name in runtime.FragmentNames)
            {
                byte[] utf8 = Encoding.UTF8.GetBytes(name);
                output.Append(' ').Append(utf8.Length == 0 ? "-" : BitConverter.ToString(utf8).Replace("-", "").ToLowerInvariant());
            }
            output.Append('\n');
        }
        if (Array.IndexOf(args, "--describe") >= 0)
            Describe(output, runtime);
        if (Array.IndexOf(args, "--children") >= 0)
        {
            output.Append("children");
            for (int g = runtime.Fragments; g < runtime.AllFragments; g++)
                output.Append(' ').Append(Hex(runtime.AnyFragmentName(g)));
            output.Append('\n');
        }
        bool structure = Array.IndexOf(args, "--structure") >= 0;
        double[] health = null, objectState = runtime.NewObjectState();
        string line;
        while ((line = Console.In.ReadLine()) != null)
        {
            string[] t = line.Split(new[] { ' ', '\t' }, StringSplitOptions.RemoveEmptyEntries);
            if (t.Length == 0)
                continue;
            if (t[0] == "start")
            {
                health = health ?? runtime.NewState();
                if (t.Length == 2 && t[1] == "new")
                {
                    runtime.ResetState(health);
                    continue;
                }
                var bytes = new byte[8 * (t.Length - 1)];
                for (int i = 1; i < t.Length; i++)
                {
                    ulong bits = Convert.ToUInt64(t[i], 16);
                    for (int b = 0; b < 8; b++) // little-endian, as a game saves a state
                        bytes[8 * (i - 1) + b] = (byte)(bits >> (8 * b));
                }
                FractureStatus loaded = runtime.StateFromBytes(bytes, health);
                if (loaded != FractureStatus.Ok)
                    output.Append("start-error ").Append(loaded).Append('\n');
                continue;
            }
            if (t[0] == "object") // levels (tests/levels_support.py): the object state of the next hits
            {
                double[] next = t.Length == 2 && t[1] == "new" ? runtime.NewObjectState() : new double[t.Length - 1];
                for (int i = 1; i < t.Length && !(t.Length == 2 && t[1] == "new"); i++)
                    next[i - 1] = FromBits(t[i]);
                if (runtime.CheckObjectState(next) == FractureStatus.Ok)
                    objectState = next;
                else
                    output.Append("object-error State\n");
                continue;
            }
            if (t[0] == "hit")
            {
                HitPiece(runtime, t, objectState, output);
                continue;
            }
            if (t[0] == "body")
            {
                var rest = new string[t.Length - 2];
                Array.Copy(t, 2, rest, 0, rest.Length);
                Answer(runtime.Body(int.Parse(t[1], CultureInfo.InvariantCulture)), rest, null, structure, output);
                continue;
            }
            Answer(runtime, t, health, structure, output);
        }
        Console.Out.Write(output.ToString());
        return 0;
    }

    // One impact line: Project, or Hit on `health` when a state was started.
    static void Answer(FractureRuntime runtime, string[] t, double[] health, bool structure, StringBuilder output)
    {
        var impact = new FractureImpact(runtime);
        var groupsOnly = new FractureImpact(runtime) { ComputeDisplacement = false };
        double[] copy = runtime.NewState();
        {
            double threshold = t[6] == "-" ? runtime.DefaultThreshold : FromBits(t[6]);
            double px = FromBits(t[0]), py = FromBits(t[1]), pz = FromBits(t[2]);
            double nx = FromBits(t[3]), ny = FromBits(t[4]), nz = FromBits(t[5]);
            if (health != null)
                Array.Copy(health, copy, health.Length);
            FractureStatus status = health != null ? runtime.Hit(health, px, py, pz, nx, ny, nz, threshold, impact)
                                                   : runtime.Project(px, py, pz, nx, ny, nz, threshold, impact);
            if (status != FractureStatus.Ok)
            {
                output.Append("error ").Append(status).Append('\n');
                if (structure)
                    AppendStructure(output, null, health);
                return;
            }
            // The same hit asking for less (and on a copy of the state before it): the same answer and state.
            if (health != null)
                runtime.Hit(copy, px, py, pz, nx, ny, nz, threshold, groupsOnly);
            else
                runtime.Project(px, py, pz, nx, ny, nz, threshold, groupsOnly);
            if (groupsOnly.Site != impact.Site || groupsOnly.NumGroups != impact.NumGroups ||
                groupsOnly.NumBroken != impact.NumBroken || groupsOnly.NumCracked != impact.NumCracked ||
                !Same(groupsOnly.Groups, impact.Groups) || (health != null && !SameBits(copy, health)))
            {
                output.Append("error inconsistent\n");
                if (structure)
                    AppendStructure(output, null, health);
                return;
            }
            output.Append("ok ").Append(impact.Site).Append(' ').Append(impact.NumGroups).Append(" g");
            foreach (int g in impact.Groups)
                output.Append(' ').Append(g);
            output.Append(" b");
            for (int m = 0; m < impact.Broken.Length; m++)
                if (impact.Broken[m])
                    output.Append(' ').Append(m);
            output.Append(" a");
            foreach (double a in impact.Alpha)
                output.Append(' ').Append(Bits(a));
            output.Append(" d");
            foreach (double x in impact.Displacement)
                output.Append(' ').Append(Bits(x));
            output.Append('\n');
            if (structure)
                AppendStructure(output, impact, health);
        }
    }

    static string Hex(string name)
    {
        byte[] utf8 = Encoding.UTF8.GetBytes(name);
        return utf8.Length == 0 ? "-" : BitConverter.ToString(utf8).Replace("-", "").ToLowerInvariant();
    }

    // A "hit" line (tests/levels_support.py): HitPiece on the object state, then every piece of the object.
    static void HitPiece(FractureRuntime runtime, string[] t, double[] state, StringBuilder output)
    {
        FracturePieceHit hit;
        double[] v = new double[6];
        for (int i = 0; i < 6; i++)
            v[i] = FromBits(t[2 + i]);
        double? threshold = t[8] == "-" ? (double?)null : FromBits(t[8]);
        FractureStatus status = runtime.HitPiece(state, int.Parse(t[1], CultureInfo.InvariantCulture), v[0], v[1], v[2], v[3],
                                                 v[4], v[5], threshold, out hit);
        if (status != FractureStatus.Ok)
        {
            output.Append("piece error ").Append(status);
        }
        else
        {
            output.Append("piece ok ").Append(hit.Body).Append(' ').Append(hit.Result.Site).Append(' ').Append(hit.ChildBody)
                  .Append(' ').Append(hit.ChildResult != null ? hit.ChildResult.Site : -1).Append(' ').Append(hit.Split ? 1 : 0).Append(" b");
            for (int m = 0; m < hit.Result.Broken.Length; m++)
                if (hit.Result.Broken[m])
                    output.Append(' ').Append(m);
            output.Append(" c");
            for (int m = 0; hit.ChildResult != null && m < hit.ChildResult.Broken.Length; m++)
                if (hit.ChildResult.Broken[m])
                    output.Append(' ').Append(m);
            var pieces = runtime.ObjectPieces(state);
            output.Append(" p");
            foreach (FracturePiece piece in pieces)
                output.Append(' ').Append(string.Join(",", piece.Fragments.ConvertAll(g => g.ToString(CultureInfo.InvariantCulture)).ToArray()));
            output.Append(" y");
            foreach (FracturePiece piece in pieces)
                output.Append(piece.Anchored ? " 1" : " 0");
        }
        output.Append(" h");
        foreach (double h in state)
            output.Append(' ').Append(Bits(h));
        output.Append('\n');
    }

    static void Describe(StringBuilder output, FractureRuntime runtime)
    {
        int features = (runtime.Criterion == "stress" ? 1 : 0) | (runtime.HasAnchors ? 2 : 0) | (runtime.HasDamage ? 4 : 0) |
                       (runtime.NumBodies > 1 ? 8 : 0);
        output.Append("describe f ").Append(features).Append(" c ").Append(Bits(runtime.CrackLevel));
        output.Append(" r ").Append(Bits(runtime.DamageRate)).Append(runtime.HasAnchors ? " y" : " y -");
        for (int j = 0; runtime.HasAnchors && j < runtime.Fragments; j++)
            output.Append(runtime.IsAnchored(j) ? " 1" : " 0");
        output.Append(" n");
        int first;
        for (int m = 0; m < runtime.Edges; m++)
            output.Append(' ').Append(runtime.CrackSegments(m, out first));
        output.Append(" s");
        for (int m = 0; m < runtime.Edges; m++)
        {
            int count = runtime.CrackSegments(m, out first);
            for (int segment = first; segment < first + count; segment++)
                for (int end = 0; end < 2; end++)
                    for (int axis = 0; axis < 3; axis++)
                        output.Append(' ').Append(Bits(runtime.CrackSegmentCoordinate(segment, end, axis)));
        }
        output.Append('\n');
    }

    // The --structure line (impact null for a refused one); the state as the bytes a game saves.
    static void AppendStructure(StringBuilder output, FractureImpact impact, double[] health)
    {
        output.Append("structure c");
        for (int m = 0; impact != null && m < impact.Cracked.Length; m++)
            if (impact.Cracked[m])
                output.Append(' ').Append(m);
        output.Append(" y");
        for (int j = 0; impact != null && j < impact.Anchored.Length; j++)
            output.Append(impact.Anchored[j] ? " 1" : " 0");
        if (health != null)
        {
            output.Append(" h");
            byte[] bytes = FractureRuntime.StateToBytes(health);
            for (int m = 0; m < health.Length; m++)
            {
                ulong bits = 0;
                for (int b = 7; b >= 0; b--)
                    bits = bits << 8 | bytes[8 * m + b];
                output.Append(' ').Append(bits.ToString("x16"));
            }
        }
        output.Append('\n');
    }

    static bool SameBits(double[] a, double[] b)
    {
        for (int i = 0; i < a.Length; i++)
            if (BitConverter.DoubleToInt64Bits(a[i]) != BitConverter.DoubleToInt64Bits(b[i]))
                return false;
        return true;
    }

    static bool Same(int[] a, int[] b)
    {
        for (int i = 0; i < a.Length; i++)
            if (a[i] != b[i])
                return false;
        return true;
    }

    static int Bench(FractureRuntime runtime, int rounds)
    {
        var hits = new System.Collections.Generic.List<double[]>();
        string line;
        while ((line = Console.In.ReadLine()) != null)
        {
            string[] t = line.Split(new[] { ' ', '\t' }, StringSplitOptions.RemoveEmptyEntries);
            if (t.Length < 7)
                continue;
            var hit = new double[7];
            for (int i = 0; i < 6; i++)
                hit[i] = FromBits(t[i]);
            hit[6] = t[6] == "-" ? runtime.DefaultThreshold : FromBits(t[6]);
            hits.Add(hit);
        }
        var impact = new FractureImpact(runtime) { ComputeDisplacement = false };
        var times = new double[hits.Count * rounds];
        double tick = 1e9 / System.Diagnostics.Stopwatch.Frequency;
        int calls = 0;
        for (int r = 0; r < rounds + 1; r++) // round 0 warms up the JIT, not timed
            foreach (double[] h in hits)
            {
                long t0 = System.Diagnostics.Stopwatch.GetTimestamp();
                runtime.Project(h[0], h[1], h[2], h[3], h[4], h[5], h[6], impact);
                long t1 = System.Diagnostics.Stopwatch.GetTimestamp();
                if (r > 0)
                    times[calls++] = (t1 - t0) * tick;
            }
        Array.Sort(times);
        Console.WriteLine(string.Format(CultureInfo.InvariantCulture, "median_ns {0:F1} p99_ns {1:F1} calls {2}",
                                        times[calls / 2], times[(int)(0.99 * (calls - 1))], calls));
        return 0;
    }
}
